"""The package's floor plan: one layer per folder, no import cycles, a library that stands without
the simulator, citations that resolve inside the repository, a command line of one module per
command, and package docstrings that map their modules.

Read from the source (ast), not by importing: an import inside a function counts as much as one
at the top of a module.
"""
import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# each package and the folder it lives in: the simulator sits in sitl/, under its own import name
PACKAGES = {"apmcal": ROOT / "apmcal", "apmcal_sim": ROOT / "sitl" / "apmcal_sim"}


def module_name(path: Path, package_dir: Path) -> str:
    parts = list(path.relative_to(package_dir.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p, d): p for d in PACKAGES.values() for p in d.rglob("*.py")}


def resolve(name: str) -> str | None:
    """The module of ours that ``name`` (a module or a name inside one) lives in."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def imports_of(module: str) -> set[str]:
    """Every module of ours that ``module`` imports, anywhere in its code."""
    path = MODULES[module]
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(filter(None, (resolve(a.name) for a in node.names)))
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(parts + ([base] if base else []))
            for alias in node.names:
                target = resolve(f"{base}.{alias.name}") or resolve(base)
                if target:
                    found.add(target)
    found.discard(module)
    return found


GRAPH = {m: imports_of(m) for m in MODULES}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one node (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    return found


def folder(module: str) -> str:
    """The room a module stands in: its package below the top (apmcal.solvers, apmcal_sim, ...)."""
    parts = module.split(".")
    return ".".join(parts[:2]) if len(parts) > 2 or (ROOT / Path(*parts)).is_dir() else module


def test_no_import_cycle_between_modules():
    assert cycles(GRAPH) == []


def test_no_import_cycle_between_folders():
    rooms: dict[str, set[str]] = {}
    for module, targets in GRAPH.items():
        rooms.setdefault(folder(module), set()).update(
            folder(t) for t in targets if folder(t) != folder(module))
    assert cycles(rooms) == []


def test_the_library_never_imports_the_simulator():
    offenders = {m: sorted(t for t in ts if t.startswith("apmcal_sim"))
                 for m, ts in GRAPH.items() if m.startswith("apmcal.") or m == "apmcal"}
    assert {m: ts for m, ts in offenders.items() if ts} == {}


def test_the_browser_interface_calls_the_library_not_the_command_line():
    """apmcal.ui sits beside the command line: the `ui` command starts it, and it never imports
    a command module (their printing is for the terminal)."""
    offenders = {m: sorted(t for t in ts if t.startswith("apmcal.cli"))
                 for m, ts in GRAPH.items() if m.startswith("apmcal.ui")}
    assert {m: ts for m, ts in offenders.items() if ts} == {}
    assert "apmcal.ui.server" in GRAPH["apmcal.cli.ui"]


def test_the_simulator_lives_in_sitl_under_a_name_that_cannot_clash():
    """sitl/ holds the simulator and the driver of ArduPilot's SITL; installed beside apmcal, the
    simulator keeps the import name apmcal_sim (a bare "sitl" could clash with another package),
    and the driver is not installed at all."""
    import tomllib

    assert (ROOT / "sitl" / "apmcal_sim" / "__init__.py").exists()
    assert not (ROOT / "apmcal_sim").exists() and not (ROOT / "sitl" / "__init__.py").exists()
    found = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"]
    assert found["where"] == [".", "sitl"]
    assert all(name.startswith("apmcal") for name in found["include"])


def test_at_most_four_modules_at_the_top_of_the_package():
    top = sorted(p.name for p in (ROOT / "apmcal").glob("*.py"))
    assert len(top) <= 4, top


def test_the_command_line_is_one_module_per_command():
    from apmcal.cli import COMMANDS, build_parser

    parser = build_parser()
    subcommands = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    assert sorted(subcommands.choices) == sorted(COMMANDS)
    for name, module in COMMANDS.items():
        assert module.__name__ == f"apmcal.cli.{name}"
        assert callable(module.add_parser) and callable(module.run)


FORBIDDEN = [(re.compile(r"\bseeds? 00\d", re.I), "a paper's file handle"),
             (re.compile(r"\.\./shared"), "a path outside the repository"),
             (re.compile(r"\bissues? #?\d+", re.I), "an issue number instead of the rule")]


@pytest.mark.parametrize("pattern, what", FORBIDDEN, ids=[w for _, w in FORBIDDEN])
def test_package_code_cites_nothing_outside_the_repository(pattern, what):
    hits = [f"{p.relative_to(ROOT)}:{i}" for p in MODULES.values()
            for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert hits == [], f"{what} in {hits}"


REFERENCES = ROOT / "docs" / "references.md"
FACTS = ROOT / "docs" / "ardupilot-facts.md"
# bracketed capitalised words that are not citations: units and names in type hints
NOT_KEYS = {"Hz", "Gauss", "None", "True", "False"}


def test_every_citation_key_in_the_code_is_in_the_references():
    keys = set(re.findall(r"^## \[([^\]]+)\]", REFERENCES.read_text(), re.M))
    assert {"Niespodziany", "Chow", "Oppong", "Ferraris", "Guerrier", "IEEE952",
            "NIST1065"} <= keys
    cited = {}
    for path in MODULES.values():
        for key in re.findall(r"(?<![\w\]])\[([A-Z][a-z][A-Za-z0-9-]*)\]", path.read_text()):
            if key not in NOT_KEYS:
                cited.setdefault(key, path.relative_to(ROOT))
    assert {"Oppong", "Chow", "Niespodziany"} <= set(cited)
    missing = {k: str(p) for k, p in cited.items() if k not in keys and not _is_a_class(k)}
    assert missing == {}


def _is_a_class(name: str) -> bool:
    """A class of ours named in brackets (``list[StaticSegment]``), not a citation."""
    return any(re.search(rf"^class {name}\b", p.read_text(), re.M) for p in MODULES.values())


def test_every_ardupilot_facts_section_the_code_cites_exists():
    sections = set(re.findall(r"^###? (.+?)\s*$", FACTS.read_text(), re.M))
    cited = set()
    for path in MODULES.values():
        for name in re.findall(r'ardupilot-facts(?:\.md)?,?\s+"([^"]+)"', path.read_text()):
            cited.add(" ".join(re.sub(r"\n\s*#", " ", name).split()))  # a comment runs on
    assert cited, "the code cites the facts document by section"
    unknown = {c for c in cited if not any(s.startswith(c) for s in sections)}
    assert unknown == set(), sorted(sections)


def test_every_package_docstring_maps_its_modules():
    unmapped = {}
    for init in (ROOT / "apmcal").rglob("__init__.py"):
        if init.parent == ROOT / "apmcal":
            continue            # the top maps its subpackages, checked below
        doc = ast.get_docstring(ast.parse(init.read_text())) or ""
        children = [p.stem for p in init.parent.glob("*.py")
                    if p.name != "__init__.py" and not p.stem.startswith("_")]
        children += [p.name for p in init.parent.iterdir() if (p / "__init__.py").exists()]
        missing = [c for c in children if not re.search(rf"\b{c}\b", doc)]
        if missing:
            unmapped[str(init.relative_to(ROOT))] = missing
    top = ast.get_docstring(ast.parse((ROOT / "apmcal" / "__init__.py").read_text()))
    subpackages = [p.name for p in (ROOT / "apmcal").iterdir() if (p / "__init__.py").exists()]
    missing_top = [s for s in subpackages if f"{s}/" not in top]
    assert unmapped == {} and missing_top == []
