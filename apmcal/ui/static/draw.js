// apmcal ui: the vehicle's pose and the compass's sphere, drawn on <canvas> (no library).
//
// Frames: the vehicle's body frame is ArduPilot's (x nose, y right, z down). Its pose comes
// from the specific force it feels at rest, f (level: (0, 0, -g)): "up" in the body frame is
// f / |f|, and the vehicle is drawn turned by the smallest rotation taking that to the
// world's up. Heading is unknown from gravity alone: the nose is drawn away from the viewer.
"use strict";

const Draw = (() => {
  const norm = (v) => Math.hypot(v[0], v[1], v[2]);
  const unit = (v) => { const n = norm(v) || 1; return [v[0] / n, v[1] / n, v[2] / n]; };
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                           a[0] * b[1] - a[1] * b[0]];
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const apply = (R, v) => [dot(R[0], v), dot(R[1], v), dot(R[2], v)];

  // rotation matrix about unit axis k by angle a (Rodrigues)
  function rotation(k, a) {
    const c = Math.cos(a), s = Math.sin(a), t = 1 - c;
    const [x, y, z] = k;
    return [[t * x * x + c, t * x * y - s * z, t * x * z + s * y],
            [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
            [t * x * z - s * y, t * y * z + s * x, t * z * z + c]];
  }

  // body -> world (x forward, y right, z down) for the body-frame up direction `up`
  function attitude(f) {
    const up = unit(f), worldUp = [0, 0, -1];
    const axis = cross(up, worldUp), s = norm(axis), c = dot(up, worldUp);
    if (s < 1e-6) {
      return c > 0 ? rotation([1, 0, 0], 0) : rotation([1, 0, 0], Math.PI);   // on its back
    }
    return rotation(unit(axis), Math.atan2(s, c));
  }

  // world (x forward, y right, z down) -> screen: seen from behind, left and above
  const AZ = -0.5, EL = 0.45;
  function project(p, cx, cy, scale) {
    const X = p[1], Y = p[0], Z = -p[2];                 // right, forward, up
    const x1 = X * Math.cos(AZ) - Y * Math.sin(AZ);
    const y1 = X * Math.sin(AZ) + Y * Math.cos(AZ);
    const up = Z * Math.cos(EL) + y1 * Math.sin(EL);
    const depth = y1 * Math.cos(EL) - Z * Math.sin(EL);
    return { x: cx + scale * x1, y: cy - scale * up, depth };
  }

  // the vehicle: a flat box (top blue, bottom dark, nose red) with an arrow to the nose
  const L = 1.0, W = 0.7, H = 0.18;
  const V = [];
  for (const x of [-L, L]) for (const y of [-W, W]) for (const z of [-H, H]) V.push([x, y, z]);
  const idx = (x, y, z) => ((x > 0) << 2) | ((y > 0) << 1) | (z > 0);
  const FACES = [
    { v: [idx(-1, -1, -1), idx(1, -1, -1), idx(1, 1, -1), idx(-1, 1, -1)], n: [0, 0, -1], fill: "#5aa9e6", name: "top" },
    { v: [idx(-1, -1, 1), idx(-1, 1, 1), idx(1, 1, 1), idx(1, -1, 1)], n: [0, 0, 1], fill: "#3d4451", name: "bottom" },
    { v: [idx(1, -1, -1), idx(1, -1, 1), idx(1, 1, 1), idx(1, 1, -1)], n: [1, 0, 0], fill: "#e63946", name: "nose" },
    { v: [idx(-1, -1, -1), idx(-1, 1, -1), idx(-1, 1, 1), idx(-1, -1, 1)], n: [-1, 0, 0], fill: "#a8b0bd", name: "tail" },
    { v: [idx(-1, 1, -1), idx(1, 1, -1), idx(1, 1, 1), idx(-1, 1, 1)], n: [0, 1, 0], fill: "#c7ccd4", name: "right" },
    { v: [idx(-1, -1, -1), idx(-1, -1, 1), idx(1, -1, 1), idx(1, -1, -1)], n: [0, -1, 0], fill: "#c7ccd4", name: "left" },
  ];
  const ARROW = [[-0.6, 0, -H - 0.001], [0.55, 0, -H - 0.001], [0.3, -0.25, -H - 0.001],
                 [0.55, 0, -H - 0.001], [0.3, 0.25, -H - 0.001]];

  function vehicle(canvas, f, label) {
    const g = canvas.getContext("2d"), w = canvas.width, h = canvas.height;
    g.clearRect(0, 0, w, h);
    const cx = w / 2, cy = h / 2 + 10, scale = Math.min(w, h) / 3.4;
    // the ground, under the vehicle
    g.fillStyle = "#dfe3e8";
    g.beginPath(); g.ellipse(cx, cy + scale * 1.2, scale * 1.6, scale * 0.35, 0, 0, 2 * Math.PI); g.fill();
    if (!f) {
      g.fillStyle = "#5b6575"; g.font = "14px sans-serif"; g.textAlign = "center";
      g.fillText(label || "no accelerometer data yet", cx, cy);
      return;
    }
    const R = attitude(f);
    const P = V.map((v) => project(apply(R, v), cx, cy, scale));
    const cam = project([0, 0, 0], 0, 0, 1);
    const faces = FACES.map((face) => {
      const n = apply(R, face.n);
      const tip = project(n, 0, 0, 1);
      const depth = face.v.reduce((s, i) => s + P[i].depth, 0) / 4;
      return { face, facing: tip.depth - cam.depth < 0, depth };
    }).filter((x) => x.facing).sort((a, b) => b.depth - a.depth);
    for (const { face } of faces) {
      g.beginPath();
      face.v.forEach((i, k) => (k ? g.lineTo(P[i].x, P[i].y) : g.moveTo(P[i].x, P[i].y)));
      g.closePath();
      g.fillStyle = face.fill; g.fill();
      g.strokeStyle = "#1d2430"; g.lineWidth = 1; g.stroke();
      if (face.name === "top") {
        const A = ARROW.map((v) => project(apply(R, v), cx, cy, scale));
        g.strokeStyle = "#fff"; g.lineWidth = 3; g.beginPath();
        g.moveTo(A[0].x, A[0].y); g.lineTo(A[1].x, A[1].y); g.lineTo(A[2].x, A[2].y);
        g.moveTo(A[1].x, A[1].y); g.lineTo(A[4].x, A[4].y); g.stroke();
      }
    }
    if (label) {
      g.fillStyle = "#1d2430"; g.font = "13px sans-serif"; g.textAlign = "left";
      g.fillText(label, 8, 18);
    }
  }

  // the angle [deg] between two specific forces
  function angle(a, b) {
    return Math.acos(Math.max(-1, Math.min(1, dot(unit(a), unit(b))))) * 180 / Math.PI;
  }

  // the compass's sphere: apmcal.solvers.coverage.fibonacci_sphere's points, covered green
  function fibonacci(n) {
    const out = [];
    for (let k = 0; k < n; k++) {
      const kk = k + 0.5, z = 1 - 2 * kk / n, phi = Math.PI * (1 + Math.sqrt(5)) * kk;
      const r = Math.sqrt(1 - z * z);
      out.push([r * Math.cos(phi), r * Math.sin(phi), z]);
    }
    return out;
  }

  function sphere(canvas, covered, spin) {
    const g = canvas.getContext("2d"), w = canvas.width, h = canvas.height;
    const cx = w / 2, cy = h / 2, r = Math.min(w, h) / 2 - 12;
    g.clearRect(0, 0, w, h);
    g.strokeStyle = "#8a94a6"; g.lineWidth = 1;
    g.beginPath(); g.arc(cx, cy, r, 0, 2 * Math.PI); g.stroke();
    const pts = fibonacci(covered.length);
    const c = Math.cos(spin), s = Math.sin(spin), ce = Math.cos(0.5), se = Math.sin(0.5);
    const drawn = pts.map((p, i) => {
      const x = p[0] * c - p[1] * s, y = p[0] * s + p[1] * c, z = p[2];
      const y2 = y * ce - z * se, z2 = y * se + z * ce;        // tilted toward the viewer
      return { x: cx + r * x, y: cy - r * z2, front: y2 < 0, on: covered[i] === "1" };
    }).sort((a, b) => a.front - b.front);
    for (const d of drawn) {
      g.globalAlpha = d.front ? 1 : 0.3;
      g.fillStyle = d.on ? "#1a7f37" : "#c7ccd4";
      g.beginPath(); g.arc(d.x, d.y, d.front ? 6 : 4, 0, 2 * Math.PI); g.fill();
    }
    g.globalAlpha = 1;
  }

  return { vehicle, sphere, angle };
})();
