"""What the studio's page edits, and everything computed from it, without the web server.

A design is the page's JSON: items (text, braille, or a drawing file: SVG, JSON strokes or an
image) with their place on the unrolled wall, and the [bulges] settings. It becomes a placement file
(placement.dump_placement) and is read back with load_placement, the CLI's own reader, so the
preview, the export and `bulgekit build --placement` all start from the same file's text.

    design = {"name": "part",
              "items": [{"id": "t1", "kind": "text", "text": "HI", "at": [5, 3], "size": 6,
                         "font": "futural", "letter_spacing": 0, "mirror": false, "rotate": 0},
                        {"id": "b1", "kind": "braille", "text": "Hi", "at": [5, 12], "grade": 1},
                        {"id": "d1", "kind": "file", "asset": "logo.svg", "at": [0, 0],
                         "scale": 1, "rotate": 15, "image_width": 20}],
              "bulges": {"dwell": 100, "extra": 0.1, "tolerance": 0.25, "geometric": false,
                         "spacing": 0.9, "line_width": 0.45, "fallback": false,
                         "printer": "ender3"}}

Messages go back beside the item at fault: a stroke's source names its placement entry
("text[0] ..."), map points carry their strokes' sources, and points the reference planner
never stops at are traced to the points of the map they were.
"""
from __future__ import annotations

import math
import re
import shutil
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import outputs
from ..bulge import api, mapformat, stats as _stats
from ..bulge.fallback import (DEFAULT_DWELL_MS, DEFAULT_EXTRA_E_MM, DEFAULT_TOLERANCE_MM,
                        MODE_GEOMETRIC, MODE_MARKED, Settings, StockStops)
from ..bulge.braille import wall_check
from ..bulge.mapbuild import DEFAULT_LINE_WIDTH, BuildError, too_many_message
from ..bulge.placement import PlacementError, dump_placement, load_placement
from ..errors import BulgekitError, InputError

_ENTRY_RX = re.compile(r"(?:^|: )((text|braille|strokes)\[(\d+)\])")   # a placement entry, "text[0]"
# the placement file's tables of things to draw, in the order load_placement reads them (so the
# order of its entries), and the page's item kind for each
KINDS = ("text", "braille", "strokes")
_TABLE_OF = {"text": "text", "braille": "braille", "file": "strokes"}
# Fields the page may set per item kind, as the placement file names them.
_FIELDS = {"text": ("text", "at", "size", "font", "letter_spacing", "mirror", "rotate", "face", "align"),
           "braille": ("text", "at", "grade", "table", "face", "align"),
           "file": ("at", "scale", "image_width", "curve_tolerance", "rotate", "face", "align")}
_BULGE_FIELDS = ("dwell", "extra", "tolerance", "geometric", "spacing", "line_width", "fallback",
                 "stop", "e_steps", "stop_e_steps", "printer", "firmware")
IMAGE_EXT = {".png", ".jpg", ".jpeg", ".bmp", ".gif", ".tif", ".tiff", ".webp"}
DRAWING_EXT = {".svg", ".json"} | IMAGE_EXT
MAX_ITEMS = 64


class DesignError(BulgekitError):
    """A design the page sent that cannot be used (the message says which field)."""


@dataclass
class Asset:
    """A drawing file the user gave the studio: kept in its working directory under `name`."""
    name: str
    path: Path


def safe_name(name: str, default: str = "file") -> str:
    """A file name without folders or odd characters (kept: ASCII letters, digits, . _ -) and
    with its extension, which says how it is read (логотип.svg -> file.svg)."""
    base = Path(str(name).replace("\\", "/")).name
    stem, ext = Path(base).stem, Path(base).suffix
    if not re.fullmatch(r"\.[A-Za-z0-9]{1,8}", ext):
        stem, ext = base, ""
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", stem).strip("._") or Path(default).stem
    return stem[:72] + ext


def _num(v, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise DesignError(f"{where}: expected a number, got {v!r}")
    return v


def entries(design: dict, assets: dict[str, Asset]) -> tuple[dict[str, list[dict]], list[str]]:
    """The placement file's tables per kind (KINDS: [[text]], [[braille]], [[strokes]]) and the
    item id of each entry in file order (the tables in KINDS' order)."""
    items = design.get("items", [])
    if not isinstance(items, list):
        raise DesignError("items: expected a list")
    if len(items) > MAX_ITEMS:
        raise DesignError(f"items: at most {MAX_ITEMS} items, got {len(items)}")
    tables: dict[str, list[dict]] = {k: [] for k in KINDS}
    ids: dict[str, list[str]] = {k: [] for k in KINDS}
    for k, it in enumerate(items):
        if not isinstance(it, dict):
            raise DesignError(f"items[{k}]: expected an object")
        iid = str(it.get("id", k))
        kind = it.get("kind")
        if kind not in _TABLE_OF:
            raise DesignError(f"item {iid}: unknown kind {kind!r} (text, braille or file)")
        t = {f: it[f] for f in _FIELDS[kind] if f in it}
        if kind == "file":
            a = assets.get(str(it.get("asset")))
            if a is None:
                raise DesignError(f"item {iid}: drawing file {it.get('asset')!r} is not loaded")
            t = {"file": a.name} | t
            if Path(a.name).suffix.lower() not in IMAGE_EXT:
                t.pop("image_width", None)
        if kind == "braille":               # a grade or a table, not both (the table wins)
            t = {f: v for f, v in t.items() if v is not None and v != ""}
            if "table" in t:
                t.pop("grade", None)
        tables[_TABLE_OF[kind]].append(t)
        ids[_TABLE_OF[kind]].append(iid)
        for f, v in t.items():
            if f == "at":
                if not (isinstance(v, list) and len(v) == 2):
                    raise DesignError(f"item {iid}: at: expected [u, v]")
                t["at"] = [_num(x, f"item {iid}: at") for x in v]
            elif f in ("size", "letter_spacing", "scale", "image_width", "curve_tolerance", "rotate"):
                t[f] = _num(v, f"item {iid}: {f}")
            elif f in ("face", "grade"):
                n = _num(v, f"item {iid}: {f}")
                if n != int(n) or n < 1:
                    raise DesignError(f"item {iid}: {f}: expected a whole number from 1, got {v!r}")
                t[f] = int(n)
    return tables, [i for k in KINDS for i in ids[k]]


def _dump(tables: dict[str, list[dict]], bulges: dict, header: str = "") -> str:
    return dump_placement(tables["text"], tables["strokes"], bulges, header, braille=tables["braille"])


def bulges(design: dict) -> dict:
    b = design.get("bulges", {}) or {}
    if not isinstance(b, dict):
        raise DesignError("bulges: expected an object")
    out = {}
    for f in _BULGE_FIELDS:
        if f in b and b[f] is not None:
            v = b[f]
            if f in ("dwell", "stop_e_steps") and isinstance(v, float) and v.is_integer():
                v = int(v)
            if f in ("printer", "firmware") and isinstance(v, str):
                v = v.strip()
                if not v:
                    continue
                if f == "printer":
                    v = printer_path(v)
            out[f] = v
    return out


def printer_path(v: str) -> str:
    """[bulges] printer as the page gives it: a preset's name as it is, a file's path made
    absolute (from the folder the studio runs in), so that the placement file an export writes
    names the same file wherever it is read."""
    from ..machine import PRESETS
    if v in PRESETS:
        return v
    return str(Path(v).expanduser().absolute())


def printer_model_of(b: dict, gcode: Path | None = None):
    """The printer model the stock file is written for, as `bulgekit build --placement` takes it
    ([bulges] printer and firmware, then the G-code's own settings before its first extrusion)."""
    from ..cli._util import printer_model
    from ..machine import FIRMWARES
    fw = b.get("firmware")
    if fw is not None and fw not in FIRMWARES:
        raise DesignError(f"bulges: firmware {fw!r}: one of {', '.join(FIRMWARES)}")
    try:
        return printer_model(b.get("printer"), fw, gcode)
    except BulgekitError as e:
        raise DesignError("bulges: " + str(e).replace("--printer ", "printer ")) from None


def placement_text(design: dict, assets: dict[str, Asset], file_ref=lambda a: a.name) -> str:
    tables, _ = entries(design, assets)
    for t in tables["strokes"]:
        t["file"] = file_ref(assets[t["file"]])
    try:
        return _dump(tables, bulges(design),
                     header="bulgekit placement, written by `bulgekit studio`.\n"
                            "Use: bulgekit build PART.gcode --placement THIS_FILE -o out/\n"
                            "or as a slicer post-processing step: bulgekit post-process "
                            "--placement THIS_FILE")
    except PlacementError as e:
        raise DesignError(str(e).removeprefix("placement: ")) from None


def from_placement(text: str, files: dict[str, str], assets: dict[str, Asset], scratch: Path) -> dict:
    """A design from a placement file's text (the inverse of placement_text). `files` maps the
    base name of each drawing file it names to the asset the page uploaded for it. The result
    is checked by load_placement, so what the CLI would refuse is refused with its message."""
    import tomllib
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise DesignError(f"placement file: not valid TOML: {e}") from None
    unknown = sorted(set(doc) - {*KINDS, "bulges"})
    if unknown:
        raise DesignError(f"placement file: unknown table {unknown[0]!r} (known: {', '.join(KINDS)}, bulges)")
    tables = {}
    for kind in KINDS:
        v = doc.get(kind, [])
        v = [v] if isinstance(v, dict) else v
        if not isinstance(v, list) or not all(isinstance(t, dict) for t in v):
            raise DesignError(f"placement file: '{kind}' must be one or more tables ([[{kind}]])")
        tables[kind] = v
    bulges = doc.get("bulges", {})
    if not isinstance(bulges, dict):
        raise DesignError("placement file: 'bulges' must be a table ([bulges])")
    items = [{"kind": "text"} | t for t in tables["text"]] + [{"kind": "braille"} | t for t in tables["braille"]]
    n_drawn = len(items)
    for i, t in enumerate(tables["strokes"]):
        ref = t.get("file")
        if not isinstance(ref, str):
            raise DesignError(f"placement file: strokes[{i}]: 'file' is missing")
        a = assets.get(files.get(Path(ref.replace("\\", "/")).name, ""))
        if a is None:
            raise DesignError(f"placement file: strokes[{i}].file: {ref} was not chosen with it "
                              "(choose the placement file and its drawing files together)")
        items.append({"kind": "file", "asset": a.name} | {k: v for k, v in t.items() if k != "file"})
    scratch.mkdir(parents=True, exist_ok=True)
    check = scratch / "import.toml"
    try:
        files = [t | {"file": str(assets[it["asset"]].path)} for t, it in zip(tables["strokes"], items[n_drawn:])]
        check.write_text(_dump(tables | {"strokes": files}, bulges), encoding="utf-8")
        load_placement(check)
    except PlacementError as e:
        raise DesignError("placement file: " + str(e).removeprefix("placement: ")
                          .removeprefix(f"{check}: ")) from None
    return {"items": items, "bulges": dict(bulges)}


def settings_of(b: dict) -> Settings:
    try:
        return Settings(MODE_GEOMETRIC if b.get("geometric") else MODE_MARKED,
                        b.get("dwell", DEFAULT_DWELL_MS), b.get("extra", DEFAULT_EXTRA_E_MM),
                        b.get("tolerance", DEFAULT_TOLERANCE_MM))
    except ValueError as e:
        raise DesignError(f"bulges: {e}") from None


def stops_of(b: dict, printer=None) -> StockStops:
    """How the export's stock file writes its stops, for the printer model (printer_model_of): as
    `bulgekit build --placement` reads them."""
    try:
        return StockStops(b.get("stop", "move"), b.get("e_steps"), b.get("stop_e_steps"),
                          printer if printer is not None else printer_model_of(b))
    except ValueError as e:
        raise DesignError(f"bulges: {e}") from None


def _entry_of(msg: str) -> tuple[str, int] | None:
    m = _ENTRY_RX.search(msg)
    return (m.group(2), int(m.group(3))) if m else None


def _entry_name(msg: str) -> str | None:
    m = _ENTRY_RX.search(msg)
    return m.group(1) if m else None


def _item_message(msg: str, tables: dict[str, list], entries: int) -> tuple[int | None, str]:
    """(the entry a message about a placement file is about: its index among the file's
    entries, in KINDS' order, or None; the message, without the entry when it has one)."""
    ent = _entry_of(msg)
    if ent is None:
        return None, msg
    kind, n = ent
    k = sum(len(tables[x]) for x in KINDS[:KINDS.index(kind)]) + n
    if k >= entries:
        return None, msg
    return k, _ENTRY_RX.sub("", msg, count=1).lstrip(": ").strip() or msg


@dataclass
class Preview:
    items: dict = field(default_factory=dict)     # id -> {"strokes": [[u, v, ...]], "errors": [], "warnings": []}
    points: list = field(default_factory=list)    # [u, v, x, y, z, weight, [ids], missed, over]
    errors: list = field(default_factory=list)    # not tied to an item
    warnings: list = field(default_factory=list)
    summary: dict = field(default_factory=dict)
    walls: dict | None = None                     # set when the page must redraw the walls

    def json(self) -> dict:
        out = {"items": self.items, "points": self.points, "errors": self.errors,
               "warnings": self.warnings, "summary": self.summary}
        if self.walls is not None:
            out["walls"] = self.walls
        return out


def preview(design: dict, assets: dict[str, Asset], model, gcode: Path, scratch: Path,
            check: bool, arena: int = mapformat.ARENA_BYTES) -> Preview:
    """Strokes per item, the map's points and every message, for the page. An item that fails
    is reported beside itself and left out, so the others still show; check runs the G-code
    through the reference planner to find points no move stops at (slower on large files)."""
    tables, ids = entries(design, assets)
    flat = [(kind, t) for kind in KINDS for t in tables[kind]]     # the entries, in file order
    b = bulges(design)
    out = Preview(items={i: {"strokes": [], "errors": [], "warnings": []} for i in ids})
    try:
        settings = settings_of(b)
        if "printer" in b or "firmware" in b:
            printer_model_of(b, gcode)          # said now, not first at the export
    except DesignError as e:
        out.errors.append(str(e))
        return out
    scratch.mkdir(parents=True, exist_ok=True)
    live = list(range(len(ids)))                 # entries still in the file
    pl = res = None
    for _ in range(len(ids) + 1):
        live_tables = {kind: [] for kind in KINDS}
        for k in live:
            kind, t = flat[k]
            live_tables[kind].append(t | {"file": str(assets[t["file"]].path)} if kind == "strokes" else t)
        live_ids = [ids[k] for k in live]
        if not live_ids:
            break
        path = scratch / "preview.toml"
        path.write_text(_dump(live_tables, b), encoding="utf-8")
        try:
            pl = load_placement(path)
            line_width = b.get("line_width", DEFAULT_LINE_WIDTH)
            check_walls = wall_check(pl.strokes, settings.dwell_ms, b.get("spacing"), line_width)
            if check_walls is not None:          # braille: a dot this print can make (as build)
                check_walls(model)
            res = api.build_map(model, pl.strokes, spacing=b.get("spacing"), line_width=line_width,
                                strict=False)
            break
        except (PlacementError, InputError, BuildError) as e:
            pl = res = None
            k, msg = _item_message(str(e).replace(f"{path}: ", ""), live_tables, len(live_ids))
            if k is None:
                out.errors.append(msg)
                break
            out.items[live_ids[k]]["errors"].append(msg)
            del live[k]
    if pl is None:
        return out
    # strokes per item as placed (on its face, if it names one), for drawing (the entries that
    # drew are the live items, in file order)
    by_entry = dict(zip(pl.entries, (ids[k] for k in live)))
    for st in res.strokes:
        out.items[by_entry[_entry_name(st.source)]]["strokes"].append(
            [round(c, 3) for p in st.points for c in p])
    out.warnings += res.notes
    for w in res.warnings:                       # crossing a corner, on the first layer
        k, msg = _item_message(w.replace(f"{path}: ", ""), live_tables, len(live_ids))
        (out.warnings if k is None else out.items[live_ids[k]]["warnings"]).append(msg)
    walls = model.walls
    for over, pts in ((False, res.points), (True, res.over_points)):
        for p in pts:
            owners = sorted({by_entry[e] for s in p.sources if (e := _entry_name(s))})
            out.points.append([round(p.u, 3), round(p.z - walls[p.layer].height / 2, 3), round(p.x, 3),
                               round(p.y, 3), round(p.z, 3), p.weight, owners, False, over])
    out.summary = {"points": len(res.points), "layers": len(res.layers), "map_bytes": len(res.map_bytes),
                   "spacing": res.spacing, "arena": arena, "checked": False, "over": len(res.too_many)}
    if res.too_many:
        _blame_too_many(out, res)
        return out                  # the planner's check waits until every layer fits
    over = res.overflow(arena)
    if over:
        out.warnings.append(
            f"the map's layers need {res.records_bytes} bytes, more than the printer's {arena}-byte "
            f"arena: the annotated file sends {len(over)} of them while printing "
            "(fine with `bulgekit send`, OctoPrint or SD; an upload from a terminal alone would not do)")
    if check:
        st = _stats.print_stats(gcode, res.map_bytes, settings, arena)
        out.summary.update(checked=True, stops=st.stops, dwell_s=round(st.dwell_s, 1),
                           added_s=round(st.added_s, 1), missed=len(st.missed))
        _blame_missed(out, st.missed, res, settings)
    return out


def _blame_too_many(out: Preview, res) -> None:
    """Layers over the firmware's per-layer limit: said below the views, and beside each item
    with points on them. The other layers' bumps still show; these layers' points are drawn
    red (over) and are in no map, and the export refuses the design until they fit."""
    most = mapformat.LAYER_POINTS_MAX
    out.errors.append(too_many_message(res.too_many, most, res.spacing) + " Until they fit, those "
                      "layers get no bumps (drawn red) and Export refuses the design; the items on "
                      "them say so.")
    total = {round(z, 3): n for z, n in res.too_many}
    mine: dict[str, dict[float, int]] = {}
    for pt in out.points:
        if pt[8]:
            for iid in pt[6]:
                per = mine.setdefault(iid, {})
                per[pt[4]] = per.get(pt[4], 0) + 1
    for iid, per in mine.items():
        where = ", ".join(f"z {z:.2f} mm: {total[z]} points, {k} its own" for z, k in sorted(per.items()))
        out.items[iid]["errors"].append(
            f"on {len(per)} layer(s) over the printer's {most} points per layer ({where}); those "
            "layers get no bumps: move it to another height, make it smaller or increase Spacing")


def _blame_missed(out: Preview, missed, res, settings) -> None:
    """Points the planner never stopped at, counted beside the items they belong to."""
    if not missed:
        return
    q = res.quantum_um / 1000
    per_item: dict[str, int] = {}
    loose = 0
    by_z: dict[int, list] = {}
    for pt in out.points:
        by_z.setdefault(round(pt[4] * 100), []).append(pt)
    for z, x, y in missed:
        best = min(by_z.get(round(z * 100), ()), key=lambda pt: (pt[2] - x) ** 2 + (pt[3] - y) ** 2,
                   default=None)
        if best is None or math.hypot(best[2] - x, best[3] - y) > q:
            loose += 1
            continue
        best[7] = True
        for iid in best[6]:
            per_item[iid] = per_item.get(iid, 0) + 1
    where = "outer-wall" if settings.mode == MODE_MARKED else "extruding"
    for iid, n in per_item.items():
        out.items[iid]["warnings"].append(
            f"{n} point(s) not within {settings.tolerance:.2f} mm of any {where} move: "
            "they will not bulge")
    if loose:
        out.warnings.append(f"{loose} map point(s) not reached by any move")


@dataclass
class Export:
    folder: Path
    files: list[Path]
    zip_path: Path
    build: object


def export(design: dict, assets: dict[str, Asset], gcode: Path, folder: Path, name: str) -> Export:
    """Everything a design makes, in `folder` (created here; all or nothing) and beside it as
    folder.zip: placement.toml and its drawing files, then exactly what `bulgekit build GCODE
    --placement placement.toml --fallback --preview-3d --name NAME -o folder` writes, made by
    the same calls."""
    from ..bulge import preview as pv
    # a drawing file keeps its name unless an output would take it
    # (compared without case: macOS and Windows file systems)
    taken = {"placement.toml"} | {f"{name}{ext}".lower() for ext in (".bkm", ".bulge.gcode", ".stock.gcode",
                                                                   ".stats.txt", ".preview.png", ".preview3d.png")}
    tables, _ = entries(design, assets)
    as_named = {}
    for a in (assets[t["file"]] for t in tables["strokes"]):
        if a.name not in as_named:
            n, k = a.name, 1
            while n.lower() in taken:
                k += 1
                n = f"drawing-{k}-{a.name}" if k > 2 else f"drawing-{a.name}"
            taken.add(n.lower())
            as_named[a.name] = n
    text = placement_text(design, assets, lambda a: as_named[a.name])
    zpath = folder.parent / f"{folder.name}.zip"
    # the folder is filled under its part's name and goes in place with the zip: both or
    # neither (bulgekit.outputs); what fails is said of the folder's own name
    with outputs.Outputs() as staged:
        stage = staged.part(folder, folder=True)
        try:
            with outputs.apart():
                for a, n in ((assets[k], n) for k, n in as_named.items()):
                    shutil.copyfile(a.path, stage / n)
                ppath = stage / "placement.toml"
                ppath.write_text(text, encoding="utf-8")
                pl = load_placement(ppath)
                b = pl.bulges
                settings, line_width = settings_of(b), b.get("line_width", DEFAULT_LINE_WIDTH)
                stops = stops_of(b, printer_model_of(b | {"printer": pl.printer}, gcode))
                out = api.build(gcode, pl.strokes, stage, name=name, spacing=b.get("spacing"),
                                line_width=line_width, settings=settings, write_fallback=True,
                                stops=stops, _check_walls=wall_check(pl.strokes, settings.dwell_ms,
                                                                     b.get("spacing"), line_width))
                pv.build_unrolled(out, stage / f"{name}.preview.png")
                pv.build_3d(out, stage / f"{name}.preview3d.png")
        except BulgekitError as e:
            e.args = (str(e).replace(str(stage), str(folder)),) + e.args[1:]
            raise
        made = sorted(p.name for p in stage.iterdir() if p.is_file())
        with outputs.part(zpath) as zpart, zipfile.ZipFile(zpart, "w", zipfile.ZIP_DEFLATED) as z:
            for n in made:
                z.write(stage / n, f"{folder.name}/{n}")
    return Export(folder, [folder / n for n in made], zpath, out)


def wall_view(model, max_vertices: int = 250_000) -> dict:
    """The outer walls for the page: per layer its z, bead height, length and u extent, and
    (every k-th layer, within a vertex budget) its path in 3D; their corners and faces
    (preview.wall_marks: corner lines, face numbers and the runs of layers with their faces)."""
    total = sum(len(w.xy) for w in model.walls)
    stride = max(1, math.ceil(total / max_vertices))
    layers = []
    for i, w in enumerate(model.walls):
        a, b = w.u_covered()
        row = {"z": round(w.z, 3), "h": round(w.height, 3), "length": round(w.length, 3),
               "closed": bool(w.closed), "u": [round(a, 3) if math.isfinite(a) else None,
                                                round(b, 3) if math.isfinite(b) else None]}
        if i % stride == 0 or i == len(model.walls) - 1:
            row["xy"] = np.round(w.xy, 3).ravel().tolist()
        layers.append(row)
    xy = np.concatenate([w.xy for w in model.walls])
    lo, hi = model.v_range
    from ..bulge.preview import wall_marks
    marks = wall_marks(model)
    r3 = lambda x: round(float(x), 3)
    marks = {"corners": [[r3(u), r3(a), r3(b)] for u, a, b in marks["corners"]],
             "faces": [[r3(u), r3(v), n] for u, v, n in marks["faces"]],
             "runs": [[r3(a), r3(b), [[f.number, r3(f.u0), r3(f.u1)] for f in fs]]
                      for a, b, fs in marks["runs"]]}
    return {"layers": layers, "v_range": [lo, hi], "geometric": model.geometric, "marks": marks,
            "bounds": [float(xy[:, 0].min()), float(xy[:, 1].min()), float(xy[:, 0].max()),
                       float(xy[:, 1].max())]}
