"""The package's layout (issue 26): imports flow one way, cli/studio -> jobs (bulge, litho,
printer) -> gcode -> the printer model (machine) -> base (errors, progress, parallel, outputs); no flat module comes back beside the base; the
public API (`import bulgekit as bk`) keeps its names.  Where things live: docs/host.md."""
from __future__ import annotations

import ast
from pathlib import Path

import bulgekit as bk

PKG = Path(__file__).resolve().parents[1] / "bulgekit"

# floor of each part: an import goes to a lower floor, or stays inside its own package
FLOORS = {"errors": 0, "progress": 0, "parallel": 0, "outputs": 0, "machine": 1, "gcode": 2, "bulge": 3,
          "litho": 3, "printer": 3, "studio": 4, "cli": 4}
# imports between two packages on the same floor, each with its reason
SIDEWAYS = {
    ("litho", "bulge"): "the calibration plate's labels are drawn with the stroke fonts "
                        "(bulge.strokes.text_strokes)",
    ("cli", "studio"): "`bulgekit studio` starts the studio's server",
    ("parallel", "progress"): "a forked child shows no progress: its lines would cross its parent's",
    ("outputs", "parallel"): "a failed run's parts are removed once the children that may write "
                             "them are ended (parallel.end_all)",
    ("studio", "cli"): "printing from the studio checks the printer's arena as `bulgekit send` does "
                       "(cli.io.annotated_arena, check_printer_arena)",
}
# the facade (bulgekit/__init__.py, __main__.py) sits above everything; of it, the package
# imports only the version string
FROM_FACADE = {"__version__"}
# the lithophane job by stage (issue 37): a module imports only modules of lower stages; the
# package's __init__.py is the facade over all of them
LITHO_STAGES = {"tone": 0, "options": 1, "picture": 2, "thickness": 3, "calibration": 4,
                "paths": 5, "gcode": 6, "body": 6, "backlit": 6, "stats": 7, "files": 8}
PUBLIC = ["BuildOutput", "BulgekitError", "InputError", "MODE_GEOMETRIC", "MODE_MARKED", "MODE_OFF",
          "Settings", "StockStops", "Stroke", "__version__", "annotate_gcode", "build", "build_map",
          "bulge_stats", "fallback_gcode", "load_strokes", "text_strokes", "walls"]


def modules():
    for p in sorted(PKG.rglob("*.py")):
        rel = p.relative_to(PKG.parent).with_suffix("")
        parts = list(rel.parts)
        is_init = parts[-1] == "__init__"
        if is_init:
            parts = parts[:-1]
        yield p, ".".join(parts), is_init


def part(mod):
    """The layout part a dotted module belongs to: a FLOORS key, or "facade"."""
    parts = mod.split(".")
    if len(parts) == 1 or parts[1] == "__main__":
        return "facade"
    return parts[1] if parts[1] in FLOORS else "?" + parts[1]


def imports(path, mod, is_init):
    """(line, imported module or name's module, name) for every bulgekit import, lazy ones too."""
    known = {m for _, m, _ in modules()} | {"bulgekit._scan", "bulgekit.gcode._scan"}
    pkg = mod if is_init else mod.rsplit(".", 1)[0]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")[:len(pkg.split(".")) - node.level + 1]
                full = ".".join(base + ([node.module] if node.module else []))
            else:
                full = node.module or ""
            if full.split(".")[0] != "bulgekit":
                continue
            for a in node.names:
                sub = f"{full}.{a.name}"
                yield node.lineno, (sub if sub in known else full), a.name
        elif isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == "bulgekit":
                    yield node.lineno, a.name, None


def test_imports_flow_one_way():
    bad = []
    for path, mod, is_init in modules():
        me = part(mod)
        if me == "facade":
            continue
        for line, target, name in imports(path, mod, is_init):
            there = part(target)
            where = f"{path.relative_to(PKG.parent)}:{line}: {me} imports {target}"
            if there == "facade":
                if name not in FROM_FACADE:
                    bad.append(where + f" ({name}): the facade is above every part")
            elif there.startswith("?") or me.startswith("?"):
                bad.append(where + ": a part with no floor (add it to FLOORS)")
            elif there == me:
                continue
            elif FLOORS[there] > FLOORS[me]:
                bad.append(where + ": upward")
            elif FLOORS[there] == FLOORS[me] and (me, there) not in SIDEWAYS:
                bad.append(where + ": sideways, not in SIDEWAYS")
    assert not bad, "\n".join(bad)


def test_litho_stages_flow_one_way():
    bad = []
    mods = [(p, m, i) for p, m, i in modules() if m.startswith("bulgekit.litho.")]
    assert {m.split(".")[2] for _, m, _ in mods} == set(LITHO_STAGES), "a litho module with no stage"
    for path, mod, is_init in mods:
        me = mod.split(".")[2]
        for line, target, _ in imports(path, mod, is_init):
            parts = target.split(".")
            if parts[:2] != ["bulgekit", "litho"]:
                continue
            there = parts[2] if len(parts) > 2 else "__init__"
            if there == "__init__" or LITHO_STAGES[there] >= LITHO_STAGES[me]:
                bad.append(f"{path.relative_to(PKG.parent)}:{line}: {me} imports {target}: not a lower stage")
    assert not bad, "\n".join(bad)


def test_the_floor_table_knows_every_subpackage():
    subs = {p.name for p in PKG.iterdir() if p.is_dir() and (p / "__init__.py").is_file()}
    assert subs == {k for k in FLOORS if (PKG / k).is_dir()}, "a subpackage with no floor in FLOORS"
    # a folder of .py files without __init__.py would be left out of the wheel (packages.find)
    loose = [str(p.relative_to(PKG)) for p in PKG.rglob("*.py")
             if not (p.parent / "__init__.py").is_file()]
    assert not loose, loose


def test_only_the_base_lies_flat():
    extra = {p.stem for p in PKG.glob("*.py")} - {"__init__", "__main__", "errors", "progress", "parallel", "outputs"}
    assert not extra, f"modules beside the base: {sorted(extra)}: put each in its job's subpackage"


def test_tests_are_laid_out_by_part():
    here = Path(__file__).resolve().parent
    flat = sorted(p.name for p in here.glob("test_*.py") if p.name != "test_layout.py")
    assert not flat, f"tests beside conftest.py: {flat}: put each in its part's folder"


def test_public_api_keeps_its_names():
    assert sorted(bk.__all__) == PUBLIC
    for name in PUBLIC:
        assert getattr(bk, name) is not None
    assert issubclass(bk.InputError, bk.BulgekitError)
    from bulgekit import errors
    from bulgekit.bulge import strokes
    assert bk.InputError is errors.InputError is strokes.InputError


def test_the_annotate_command_loads_no_build_module():
    """The facade's names are loaded when first asked for, and `bulgekit annotate` imports none of
    build's modules (about 0.025 s of a 100 MB annotate, docs/host.md); the names still come."""
    import subprocess
    import sys
    code = ("import sys, bulgekit, bulgekit.cli, bulgekit.bulge.annotate\n"
            "print(sorted(m for m in sys.modules if m.split('.')[-1] in "
            "('api', 'mapbuild', 'strokes', 'wall', 'stats')))\n"
            "print(bulgekit.build.__module__, bulgekit.Stroke.__module__, 'walls' in dir(bulgekit))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=PKG.parent).stdout.splitlines()
    assert out == ["[]", "bulgekit.bulge.api bulgekit.bulge.strokes True"]
