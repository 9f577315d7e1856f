"""Size of a user's install: a fresh venv, ``pip install .`` of this tree, site-packages measured.

    python benchmarks/install_size.py [--peer REV] [--keep]

Makes a virtual environment in a temporary folder (``python -m venv``), installs this tree into
it without its extras (what ``pip install apmcal`` gives a user), and prints the size of its
site-packages [MB, 10⁶ bytes, apparent file sizes summed, everything in it including pip] and
the number of distributions installed (``*.dist-info`` folders, pip and apmcal included), the ten
largest distributions, and whether the target (≤ 600 MB) is met. ``--peer REV`` measures revision REV
the same way first (``git archive`` of its whole tree, e.g. ``--peer main`` before numba and
allantools left the runtime dependencies), in the same run.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_MB = 600.0


def _size(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file() and not f.is_symlink())


def _dist_of(dist_info: Path) -> tuple[str, set[str]]:
    """(name, top-level names it installed) of one ``*.dist-info`` folder."""
    name = dist_info.name.split("-")[0]
    record = dist_info / "RECORD"
    tops = set()
    if record.exists():
        for line in record.read_text().splitlines():
            first = line.split(",")[0].split("/")[0]
            if first and not first.endswith(".dist-info") and first != "..":
                tops.add(first)
    return name, tops


def measure(site: Path) -> tuple[float, int, list[tuple[str, float]]]:
    """(site-packages MB, distributions installed, [(distribution, MB)] largest first)."""
    sizes = []
    for di in sorted(site.glob("*.dist-info")):
        name, tops = _dist_of(di)
        mb = sum(_size(site / t) if (site / t).is_dir() else (site / t).stat().st_size
                 for t in tops if (site / t).exists()) / 1e6
        sizes.append((name, mb))
    sizes.sort(key=lambda x: -x[1])
    return _size(site) / 1e6, len(sizes), sizes


def install(source: Path, tmp: Path) -> tuple[float, int, list[tuple[str, float]]]:
    """A fresh venv in ``tmp`` with ``source`` pip-installed; its :func:`measure`."""
    venv = tmp / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    py = venv / "bin" / "python"
    subprocess.run([str(py), "-m", "pip", "install", "-q", str(source)], check=True)
    site = Path(subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()"
                                "['purelib'])"], check=True, capture_output=True,
                               text=True).stdout.strip())
    return measure(site)


def report(label: str, mb: float, count: int, sizes) -> None:
    print(f"{label}: largest " + ", ".join(f"{n} {s:.0f}" for n, s in sizes[:10]) + " (MB)")
    for forbidden in ("numba", "llvmlite", "allantools", "pytest", "sphinx", "numpydoc"):
        if any(n.lower() == forbidden for n, _ in sizes):
            print(f"  {forbidden} is installed")
    print(f"{label}: site-packages {mb:.1f} MB, {count} packages")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--peer", metavar="REV", help="also measure revision REV (git archive)")
    ap.add_argument("--keep", action="store_true", help="print the venvs' folder and keep it")
    args = ap.parse_args(argv)
    tmp = Path(tempfile.mkdtemp(prefix="apmcal-install-"))
    if args.peer:
        src = tmp / "peer-src"
        src.mkdir()
        archive = subprocess.run(["git", "archive", args.peer], cwd=ROOT, check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", str(src)], input=archive, check=True)
        (tmp / "peer").mkdir()
        report(f"peer {args.peer}", *install(src, tmp / "peer"))
    (tmp / "this").mkdir()
    mb, count, sizes = install(ROOT, tmp / "this")
    report("this tree", mb, count, sizes)
    print(f"site-packages {mb:.1f} MB, {count} packages "
          f"(target ≤ {TARGET_MB:.0f} MB: {'met' if mb <= TARGET_MB else 'NOT met'})")
    if args.keep:
        print(f"kept: {tmp}")
    else:
        subprocess.run(["rm", "-rf", str(tmp)], check=True)
    return 0 if mb <= TARGET_MB else 1


if __name__ == "__main__":
    sys.exit(main())
