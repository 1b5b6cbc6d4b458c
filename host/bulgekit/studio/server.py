"""The studio's web server: one local user, one browser page, the toolkit's own API behind it.

It listens on 127.0.0.1 only and answers only its own page: every request must name this
server in Host (no DNS rebinding), a browser's Origin / Sec-Fetch-Site must be this server,
and /api and /files need the token that came with the page. It reads the G-code given on the
command line and what the page uploads, and writes only inside its working directory:

    WORKDIR/gcode/      uploaded G-code          WORKDIR/exports/NAME[-K]/ + NAME[-K].zip
    WORKDIR/assets/     drawing files, pictures  WORKDIR/litho/N-NAME/
    WORKDIR/scratch/    the preview's placement file

Long work runs as a job in a worker thread (one at a time: the toolkit's passes are CPU-bound
and report through progress.listen); the page polls /api/job/ID. Sending to a printer has its
own thread, so the page stays usable while a print streams.
"""
from __future__ import annotations

import asyncio
import base64
import hashlib
import json
import re
import secrets
import shutil
import threading
import time
import traceback
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

from aiohttp import web

from .. import outputs, progress
from ..errors import BulgekitError
from . import design as dz

STATIC = Path(__file__).resolve().parent / "static"
VENDOR_FILES = ("three.module.min.js", "OrbitControls.js")
MB = 1_000_000           # decimal, as file managers and browsers show sizes


class AssetsMissing(BulgekitError):
    pass


def check_assets() -> None:
    missing = [f for f in VENDOR_FILES if not (STATIC / "vendor" / f).is_file()]
    if missing:
        raise AssetsMissing(
            f"the studio's front-end files are missing ({', '.join(missing)} in {STATIC / 'vendor'}; "
            "the package was built without npm): install npm, then the package again "
            "(its build runs host/web/build.py, which takes three.js from npm)")


@dataclass
class Job:
    id: str
    kind: str
    state: str = "running"          # running, done, error
    label: str = ""
    done: int = 0
    total: int = 0
    result: dict | None = None
    error: str | None = None
    log: deque = field(default_factory=lambda: deque(maxlen=1000))   # printer messages: the latest
    started: float = field(default_factory=time.monotonic)

    def json(self) -> dict:
        return {"id": self.id, "kind": self.kind, "state": self.state, "label": self.label,
                "done": self.done, "total": self.total, "result": self.result, "error": self.error,
                "log": list(self.log)[-200:], "elapsed": round(time.monotonic() - self.started, 1)}


@dataclass
class Limits:
    gcode_bytes: int = 256 * MB
    asset_bytes: int = 25 * MB
    image_pixels: int = 40_000_000
    arena: int = 1024


class Studio:
    """State of the one design being edited, and the jobs working on it."""

    def __init__(self, workdir: Path, limits: Limits = Limits()):
        self.workdir = Path(workdir)
        for d in ("gcode", "assets", "exports", "litho", "scratch"):
            (self.workdir / d).mkdir(parents=True, exist_ok=True)
        self.limits = limits
        self.token = secrets.token_urlsafe(24)
        self.gcode: Path | None = None
        self.gcode_name = ""
        self.models: dict[bool, object] = {}   # the walls per mode (geometric or not), read when asked
        self.view: dict | None = None          # the walls the page draws (wall_view of one of them)
        self.assets: dict[str, dz.Asset] = {}
        self.asset_kinds: dict[str, str] = {}
        self.asset_info: dict[str, dict] = {}      # what add_asset said of each (the page's info)
        self.design: dict | None = None
        self.design_gcode = ""                  # the G-code the design was last previewed on
        self.exports: dict[str, dz.Export] = {}
        self.lithos: dict[str, dict] = {}      # key -> the lithophane's files and its 3D view
        self.litho_last: dict | None = None     # the last one made: a reloaded page shows it again
        self.jobs: dict[str, Job] = {}
        self.worker = ThreadPoolExecutor(1, thread_name_prefix="studio-work")
        self.sending = threading.Lock()
        self._n = 0
        self._lock = threading.Lock()

    def next_id(self) -> int:
        with self._lock:
            self._n += 1
            return self._n

    # -- jobs

    def start(self, kind: str, fn, *args, thread: bool = False) -> Job:
        job = Job(str(self.next_id()), kind)
        self.jobs[job.id] = job

        def run():
            def tick(label, done, total):
                job.label, job.done, job.total = label, done, total
            if not thread:
                progress.listen(tick)               # this thread's passes only (progress.py)
            try:
                job.result = fn(job, *args)
                job.state = "done"
            except (BulgekitError, ValueError, OSError) as e:
                job.error, job.state = _message(e), "error"
            except Exception as e:                  # a bug: said in the page, kept in the log
                traceback.print_exc()
                job.error, job.state = f"internal error: {type(e).__name__}: {e}", "error"
            finally:
                progress.listen(None)
        if thread:
            threading.Thread(target=run, name=f"studio-{kind}", daemon=True).start()
        else:
            self.worker.submit(run)
        return job

    # -- G-code

    def open_gcode(self, job: Job, path: Path, name: str) -> dict:
        from ..gcode import movescan
        from ..bulge import api
        job.label = "checking the file"
        with movescan.Scan(path, name).kept():     # checked and scanned once: both tries use it
            from ..bulge.wall import WallError
            try:
                model = api.walls(path)
            except WallError as e:
                if "no outer-wall feature comments" not in str(e):
                    raise WallError(str(e).replace(str(path), name)) from None
                # no comments to find the outer wall by: its outermost closed loop per layer is
                # the wall in geometric mode (M720 S2), which the page then selects
                job.log.append(f"{name}: no outer-wall feature comments; using geometric mode")
                try:
                    model = api.walls(path, geometric=True)
                except WallError as e2:
                    raise WallError(f"{name}: no outer wall found: the file has no outer-wall feature "
                                    "comments (;TYPE:External perimeter, ;TYPE:Outer wall, ...) and no "
                                    "closed extruded loops to take as the wall instead "
                                    f"({str(e2).replace(str(path), name)}). Is it a sliced print?") from None
        view = dz.wall_view(model)
        old = self.gcode
        self.gcode, self.gcode_name, self.view = path, name, view
        self.models = {model.geometric: model}
        if old is not None and old != path and self._uploaded(old):
            old.unlink(missing_ok=True)            # exports made from it keep their own files
        return self.gcode_state()

    def _uploaded(self, path: Path) -> bool:
        return path.parent == self.workdir / "gcode"

    def open_upload(self, job: Job, path: Path, name: str) -> dict:
        """open_gcode for a file the page uploaded: kept only while it is the open one."""
        try:
            return self.open_gcode(job, path, name)
        except BaseException:
            path.unlink(missing_ok=True)
            raise

    def gcode_state(self) -> dict | None:
        """The open file as the page shows it (its walls in the mode last drawn)."""
        if self.gcode is None:
            return None
        v = self.view
        return {"name": self.gcode_name, "layers": len(v["layers"]), "geometric": v["geometric"],
                "length_max": round(max(l["length"] for l in v["layers"]), 2), "walls": v,
                "bytes": self.gcode.stat().st_size}

    # -- drawing files

    def add_asset(self, name: str, data: bytes) -> dict:
        from ..bulge.strokes import load_json, load_svg
        ext = Path(name).suffix.lower()
        if ext not in dz.DRAWING_EXT:
            raise dz.DesignError(f"{name}: not a drawing file this studio reads "
                                 f"(SVG, JSON strokes or a picture: {', '.join(sorted(dz.DRAWING_EXT))})")
        base = dz.safe_name(name)
        stem, suf = Path(base).stem, Path(base).suffix.lower()
        final, k = f"{stem}{suf}", 1
        same = self.assets.get(final)
        if same is not None and same.path.read_bytes() == data:
            # the same file chosen again (a picture for a second lithophane, a drawing added
            # twice): it is the one already here, under its own name
            return self.asset_info[final]
        # another file of a name already taken: NAME-2 (the design's items may use the first);
        # unique also where case does not count (macOS, Windows)
        while final.lower() in {n.lower() for n in self.assets}:
            k += 1
            final = f"{stem}-{k}{suf}"
        path = self.workdir / "assets" / final
        path.write_bytes(data)
        try:
            info = {"name": final, "original": name, "kind": "image" if suf in dz.IMAGE_EXT else suf[1:]}
            if suf in dz.IMAGE_EXT:
                info.update(self._check_image(path, name))
            elif suf == ".svg":
                info["strokes"] = len(load_svg(str(path)))
            else:
                info["strokes"] = len(load_json(str(path)))
        except BulgekitError as e:
            path.unlink(missing_ok=True)
            raise dz.DesignError(str(e).replace(str(path), name)) from None
        except Exception as e:          # e.g. RecursionError from a JSON nested too deep
            path.unlink(missing_ok=True)
            raise dz.DesignError(f"{name}: cannot be read ({type(e).__name__}: {e})") from None
        self.assets[final] = dz.Asset(final, path)
        self.asset_kinds[final] = info["kind"]
        self.asset_info[final] = info
        return info

    def _check_image(self, path: Path, name: str) -> dict:
        from PIL import Image
        try:
            with Image.open(path) as im:
                w, h = im.size
        except Exception as e:
            raise dz.DesignError(f"{name}: not a picture Pillow can read ({e})") from None
        if w * h > self.limits.image_pixels:
            raise dz.DesignError(
                f"{name}: {w} x {h} pixels ({w * h / 1e6:.1f} megapixels) is more than this studio takes "
                f"({self.limits.image_pixels / 1e6:g}); scale it down first (a bulge is about 1 mm)")
        return {"width_px": w, "height_px": h}

    # -- design

    def model_for(self, d: dict):
        """The walls in the design's mode (the export reads them that way too)."""
        from ..bulge import api
        from ..bulge.wall import WallError
        geometric = bool(dz.bulges(d).get("geometric", False))
        if geometric not in self.models:
            try:
                self.models[geometric] = api.walls(self.gcode, geometric=geometric)
            except WallError as e:
                raise dz.DesignError(self.user_words(str(e))) from None
        return self.models[geometric]

    def user_words(self, msg: str) -> str:
        """A toolkit message as the page's user knows things: the file names they chose (not
        the working folder's copies) and the page's settings (not the CLI's options)."""
        if self.gcode is not None:
            msg = msg.replace(str(self.gcode), self.gcode_name)
        for a in self.assets.values():
            msg = msg.replace(str(a.path), a.name)
        msg = msg.replace(str(self.workdir) + "/", "")
        for cli, page in (("pass --geometric", "choose Mode: geometric (M720 S2)"),
                          ("--geometric", "Mode: geometric"), ("Use --allow-unreached to write the file anyway.", ""),
                          ("--image-width MM", "Width on the wall"), ("at --image-width", "at a width on the wall of"),
                          ("--at U,V", "u, v"), ("--spacing", "Spacing"),
                          # a drawing off the wall, said with the placement file's keys
                          ("at image_width =", "at a width on the wall of"), ("at size =", "at a size of"),
                          ("at scale =", "at a scale of"), ("at = [U, V]", "u, v")):
            msg = msg.replace(cli, page)
        return msg.strip()

    def preview(self, d: dict, check: bool) -> dict:
        if self.gcode is None:
            raise dz.DesignError("open a sliced G-code first")
        self.design = d                  # a reloaded page picks up where it was
        self.design_gcode = self.gcode_name     # (asking first if another G-code is open by then)
        try:
            model = self.model_for(d)
        except dz.DesignError as e:
            return dz.Preview(errors=[str(e)]).json()
        out = dz.preview(d, self.assets, model, self.gcode, self.workdir / "scratch", check,
                         self.limits.arena)
        if model.geometric != self.view["geometric"]:
            self.view = dz.wall_view(model)           # the page draws the walls it places on
            out.walls = self.view
        words = self.user_words
        out.errors = [words(m) for m in out.errors]
        out.warnings = [words(m) for m in out.warnings]
        for it in out.items.values():
            it["errors"] = [words(m) for m in it["errors"]]
            it["warnings"] = [words(m) for m in it["warnings"]]
        return out.json()

    def export(self, job: Job, d: dict) -> dict:
        if self.gcode is None:
            raise dz.DesignError("open a sliced G-code first")
        name = dz.safe_name(d.get("name") or Path(self.gcode_name).stem, "part")
        key = self._free_export_name(name)
        folder = self.workdir / "exports" / key
        try:
            ex = dz.export(d, self.assets, self.gcode, folder, name)
        except BulgekitError as e:
            raise dz.DesignError(self.user_words(str(e).replace(f"{folder}/", ""))) from None
        self.exports[key] = ex
        files = [{"name": p.name, "bytes": p.stat().st_size, "url": f"/files/exports/{key}/{p.name}"}
                 for p in ex.files]
        st = ex.build.stats
        return {"key": key, "folder": str(ex.folder), "files": files,
                "zip": f"/files/exports/{ex.zip_path.name}", "stats": st.text(per_layer=False),
                "notes": list(ex.build.result.notes) + list(ex.build.annotate.notes)}

    def _free_export_name(self, name: str) -> str:
        """The export's folder name: the design's (the G-code's) name, then NAME-2, NAME-3 ... for
        the next exports of it, none taken by a folder or zip already there (any case)."""
        # exports run one at a time in the worker thread, so no two pick the same name
        taken = {p.name.lower() for p in (self.workdir / "exports").iterdir()}
        k, key = 1, name
        while key.lower() in taken or f"{key}.zip".lower() in taken:
            k += 1
            key = f"{name}-{k}"
        return key

    # -- printer

    def _export_file(self, key: str, which: str) -> Path:
        ex = self.exports.get(key)
        if ex is None:
            raise dz.DesignError(f"export {key!r} is not there: export first")
        suffix = {"bulge": ".bulge.gcode", "stock": ".stock.gcode"}.get(which)
        if suffix is None:
            raise dz.DesignError(f"which: 'bulge' or 'stock', got {which!r}")
        return next(p for p in ex.files if p.name.endswith(suffix))

    def _litho_file(self, key: str, which: str) -> Path:
        made = self.lithos.get(key)
        if made is None:
            raise dz.DesignError(f"lithophane {key!r} is not there: make it first")
        if which not in ("litho", "stock"):
            raise dz.DesignError(f"which: 'litho' or 'stock', got {which!r}")
        return made["paths"]["gcode" if which == "litho" else "stock"]

    def send(self, job: Job, key: str, which: str, port: str, baud: int, litho: bool = False) -> dict:
        from ..cli.io import annotated_arena, check_printer_arena
        from ..printer.sender import Sender, read_gcode
        import click
        path = self._litho_file(key, which) if litho else self._export_file(key, which)
        lines = read_gcode(path)
        if not self.sending.acquire(blocking=False):
            raise dz.DesignError("a file is being sent already")
        try:
            job.label, job.total = f"sending {path.name}", len(lines)
            with Sender(port, baud, on_message=job.log.append) as s:
                need = annotated_arena(path)
                if need is not None:
                    try:
                        check_printer_arena(s, need, path.name)
                    except click.ClickException as e:
                        raise dz.DesignError(e.message) from None
                st = s.send(lines, progress=lambda n: setattr(job, "done", n), desc=path.name)
            return {"summary": st.summary(), "file": path.name, "errors": [list(e) for e in st.errors]}
        finally:
            self.sending.release()

    # -- lithophanes

    def litho(self, job: Job, asset: str, opts: dict, name: str | None) -> dict:
        from .. import litho as lt
        a = self.assets.get(asset)
        if a is None or Path(a.name).suffix.lower() not in dz.IMAGE_EXT:
            raise dz.DesignError("choose a picture for the lithophane first")
        known = set(lt.LithoOptions.__dataclass_fields__) - {"start_gcode", "end_gcode"}
        bad = sorted(set(opts) - known)
        if bad:
            raise dz.DesignError(f"lithophane: unknown option(s) {', '.join(bad)}")
        if "bed" in opts:
            opts["bed"] = tuple(opts["bed"])
        try:
            o = lt.LithoOptions(**opts)
        except TypeError as e:
            raise dz.DesignError(f"lithophane: {e}") from None
        # the outputs are named after the picture as the user named it (face.png: face.*), also
        # when another picture of that name came first and the copy here is face-2.png; the
        # folder's number keeps the lithophanes apart
        name = dz.safe_name(name or Path(self.asset_info[a.name]["original"]).stem, "lithophane")
        key = f"{self.next_id()}-{name}"
        folder = self.workdir / "litho" / key

        def show(done, total):
            job.label, job.done, job.total = "planning layers", done, total
        try:
            res = lt.make(a.path, folder, name=name, progress=show, options=o)
        except lt.LithoError as e:
            shutil.rmtree(folder, ignore_errors=True)
            # the toolkit names its CLI options; the page has fields with labels
            msg = re.sub(r"--[a-z-]+", lambda m: f"'{_LITHO_FIELDS.get(m.group(0), m.group(0))}'", str(e))
            raise lt.LithoError(msg.replace(str(a.path), a.name)) from None
        except BaseException:
            shutil.rmtree(folder, ignore_errors=True)
            raise
        job.label, job.done, job.total = "preparing the 3D view", 0, 0
        self.lithos[key] = {"paths": res.paths, "view": litho_view(res.plan)}
        files = [{"name": p.name, "bytes": p.stat().st_size, "url": f"/files/litho/{key}/{p.name}"}
                 for p in sorted(folder.iterdir())]
        out = {"key": key, "files": files, "figures": litho_figures(res.stats),
               "look": f"/files/litho/{key}/{res.paths['png'].name}", "view": f"/api/litho/{key}/view"}
        # what a reloaded page needs to show it again: the result, the picture and the form
        self.litho_last = out | {"picture": self.asset_info[a.name], "options": opts}
        return out


def printer_choices() -> list[dict]:
    """The printer models the page offers for the stock file: the presets (bulgekit.machine),
    each with its firmware, E steps/mm and the line its stock file's header gives."""
    from ..machine import PRESETS
    return [{"name": n, "firmware": m.firmware, "e_steps": m.e_steps, "describe": m.describe()}
            for n, m in PRESETS.items()]


def litho_choices() -> dict:
    """What the lithophane form offers, from the toolkit itself: the shapes, the curves, the ways
    of laying light tones and the defaults of every option (so the page follows a toolkit that adds a curve or changes one)."""
    import dataclasses
    from .. import litho as lt
    # None (chosen by the toolkit, e.g. the height from the picture) leaves the field empty, and
    # an empty field is not sent
    defaults = {f.name: f.default for f in dataclasses.fields(lt.LithoOptions)
                if f.default is None or isinstance(f.default, (int, float, str, bool))}
    return {"shapes": list(lt.SHAPES), "curves": list(lt.CURVES), "light_gaps": list(lt.LIGHT_GAPS),
            "defaults": defaults}


def _b64(a) -> str:
    import numpy as np
    return base64.b64encode(np.ascontiguousarray(a).tobytes()).decode()


def _predicted_look(plan):
    """The predicted backlit look on the layer x sample grid, bottom row first, as the sRGB values
    0..1 of the look PNG's unstretched panel (litho.look() gives L*)."""
    from .. import litho as lt
    from ..litho import tone
    return tone.to_srgb(tone.luminance(lt.look(plan)[1]))


VIEW_CELLS = 256        # the 3D view's mesh: at most this many rows and columns (the look is a texture)
VIEW_TEXELS = 1024      # the look's texture: at most this many texels a side


def litho_view(plan) -> dict:
    """What the page's 3D view draws: the relief as a height field (the printed thickness, in um,
    on a grid of at most VIEW_CELLS a side; a 240 x 220 px picture at the defaults has 460 x 251
    samples, of which the view keeps 230 x 251) and the predicted look as a texture on it (uint8,
    up to VIEW_TEXELS a side, so the picture stays sharp where the mesh is coarse). `s` is along
    the part (mm on a plate, radians round a cylinder, radians from `arc_start` on an arc), `z`
    up from the bed, mm."""
    import numpy as np
    from .. import litho as lt
    o, fld = plan.options, plan.field
    t = np.asarray(lt.printed_thickness(plan), dtype=float)        # (rows, samples), bottom first
    pred = np.clip(np.nan_to_num(np.asarray(_predicted_look(plan), dtype=float)), 0.0, 1.0)
    rows, cols = t.shape

    def picks(n, most):
        k = int(np.ceil(n / most))
        i = np.arange(0, n, k)
        return i if i[-1] == n - 1 else np.append(i, n - 1)    # keep the last row / column
    ri, ci = picks(rows, VIEW_CELLS), picks(cols, VIEW_CELLS)
    ti, tj = picks(rows, VIEW_TEXELS), picks(cols, VIEW_TEXELS)
    H = o.layer_height
    z0 = fld.n_foot * H
    out = {"shape": o.shape, "rows": len(ri), "cols": len(ci),
           "s": [round(float(v), 5) for v in fld.s[ci]],
           "z": [round(z0 + (float(i) + 0.5) * H, 4) for i in ri],
           "z_range": [z0, round(z0 + rows * H, 4)],
           # where each row and column falls on the look's texture (texel centres, 0..1)
           "u": [round((float(j) + 0.5) / cols, 6) for j in ci],
           "v": [round((float(i) + 0.5) / rows, 6) for i in ri],
           "thickness_um": _b64(np.round(t[np.ix_(ri, ci)] * 1000).astype("<u2")),
           "max_thickness": o.max_thickness,
           "look": {"width": len(tj), "height": len(ti),
                    "data": _b64(np.round(pred[np.ix_(ti, tj)] * 255).astype(np.uint8))},
           "foot": None}
    if o.shape in ("cylinder", "arc"):
        out["r_in"] = o.diameter / 2 - o.max_thickness
        if o.shape == "arc":                                   # where its samples' angles start
            from ..litho.paths import arc_start
            out["arc_start"] = round(arc_start(fld), 6)
    elif fld.n_foot:
        out["foot"] = {"depth": o.foot, "height": z0}
    return out


def _duration(s: float) -> str:
    if s < 60:
        return f"{s:.0f} s"
    m = round(s / 60)
    return f"{m} min" if m < 60 else f"{m // 60} h {m % 60:02d} min"


def litho_figures(st: dict) -> list:
    """The lithophane's figures in the page's words: [label, value] pairs. Keys that a toolkit
    version does not write are left out."""
    out = []
    est = st.get("estimate") or {}
    if est.get("estimated_time_s_gcode") is not None:
        out.append(["Print time", _duration(est["estimated_time_s_gcode"]) + " (bulgekit firmware)"])
    if est.get("estimated_time_s_stock") is not None:
        out.append(["Print time, stock firmware", _duration(est["estimated_time_s_stock"])])
    machine = est.get("machine") or st.get("machine")
    if isinstance(machine, dict) and machine:         # what the times assume, when the toolkit says
        out.append(["Times assume", _machine_words(machine)])
    size = st.get("size_mm") or {}
    if size:
        out.append(["Picture", f"{round(size['picture_width'], 1):g} × {round(size['picture_height'], 1):g} mm"
                               + (" around" if st.get("shape") == "cylinder" else "")])
    if isinstance(st.get("picture"), dict) and st["picture"].get("note"):
        out.append(["How the picture lies", st["picture"]["note"]])   # what was chosen, cropped, fitted
    sd = st.get("stands")
    if isinstance(sd, dict) and "footprint_margin_mm" in sd:
        out.append(["Stands by itself", f"yes: centre of mass {sd['footprint_margin_mm']:.1f} mm inside its "
                    f"footprint, tips when leaned {sd['tip_angle_deg']:.1f}°" if sd.get("stands") else
                    f"no: centre of mass {-sd['footprint_margin_mm']:.1f} mm outside its footprint"])
    if "layers" in st:
        out.append(["Layers", f"{st['layers']:,}"
                              + (f", {size['height']:g} mm tall" if "height" in size else "")])
    if "filament_mm" in st:
        vol = f", {st['deposited_mm3'] / 1000:.1f} cm³" if "deposited_mm3" in st else ""
        out.append(["Filament", f"{st['filament_mm'] / 1000:.2f} m{vol}"])
    if "fill_ratio" in st:
        out.append(["Filled", f"{100 * st['fill_ratio']:.1f} % of the part's volume"])
    rates = st.get("rates") or {}
    if "mid_line_mm3_s" in rates:
        low = rates.get("mid_line_lowered_for_accel_mm_s2")
        out.append(["Mid-line flow", f"{rates['mid_line_mm3_s']:g} mm³/s"
                    + (f" (lowered for a printer at {low:g} mm/s²: steadier, slower)" if low else "")])
    ml, opts = st.get("mid_line") or {}, st.get("options") or {}
    if "max_speed" in opts:
        held = (f", held for {100 * ml['capped_time_share']:.1f} % of the mid-line's time"
                if "capped_time_share" in ml else "")
        out.append(["Fastest head speed", f"{opts['max_speed']:g} mm/s{held}"])
    gaps = st.get("gaps") or {}
    if "snapped_share" in gaps:
        out.append(["Gaps too narrow for a line", f"{100 * gaps['snapped_share']:.2f} % of the samples"])
    if gaps.get("narrowed_share"):
        out.append(["Light tones", f"a thin mid-line between narrower walls, {100 * gaps['narrowed_share']:.1f} % "
                                   "of the samples"])
    if gaps.get("shared_share"):
        out.append(["Light tones", f"the walls share the gap, {100 * gaps['shared_share']:.1f} % of the samples"])
    walls = st.get("walls") or {}
    if "back_mm" in walls and "front_mm" in walls:
        b, f = walls["back_mm"], walls["front_mm"]
        out.append(["Walls", f"back mostly {b['median']:.2f} mm wide ({b['min']:.2f}–{b['max']:.2f}), "
                             f"front {f['min']:.2f}–{f['max']:.2f} mm"])
    if "extruding_moves" in st:
        out.append(["Moves", f"{st['extruding_moves']:,}"])
    out += _look_figures(st.get("look") or {})
    return out


def _machine_words(m: dict) -> str:
    """The estimate's machine (litho.machine_words) in the page's words; keys it does not know
    are shown under their own name."""
    m = dict(m)
    parts = []
    if "accel_mm_s2" in m:
        a, t = m.pop("accel_mm_s2"), m.pop("travel_accel_mm_s2", None)
        parts.append(f"acceleration {a:g} mm/s²" + (f" (travel {t:g})" if t is not None and t != a else ""))
    if "junction_deviation_mm" in m:
        jerk = m.pop("classic_jerk", None)
        jd = m.pop("junction_deviation_mm")
        if isinstance(jerk, dict):                    # per axis (X, Y, Z, E)
            jerk = list(jerk.values())
        parts.append(f"classic jerk {'/'.join(f'{j:g}' for j in jerk)} mm/s" if jerk
                     else f"junction deviation {jd:g} mm")
    if "lookahead_blocks" in m:
        n = m.pop("lookahead_blocks")
        parts.append("look-ahead over the whole file" if n is None else f"look-ahead of {n} moves")
    m.pop("min_segment_steps", None)                  # Marlin's rule for tiny moves: always
    parts += [f"{k.replace('_', ' ')} {v}" for k, v in m.items()]
    return ", ".join(parts)


# the look block's figures as the page words them; numbers without a word here are shown under
# their key (a newer toolkit may add some), words and settings (curve, attenuation) are left out
# (the model against itself, the likeness figures of before issue 37, is not shown: a maker
# read it as a promise about the print)
_LOOK_SKIP = {"attenuation_per_mm", "curve", "mean_dL", "mean_abs_dL", "ssim_L", "ssim", "correlation"}


def _look_figures(lk: dict) -> list:
    out = []
    for k, v in lk.items():
        if k in _LOOK_SKIP:
            continue
        if k == "picture_vs_print":
            if isinstance(v, dict) and isinstance(v.get("mean_abs_dL"), (int, float)):
                ssim = "n/a" if v.get("ssim_L") is None else f"{v['ssim_L']:.2f}"
                out.append(["Picture vs the print as sampled (a model)",
                            f"mean {v['mean_abs_dL']:.1f} ΔL*, SSIM {ssim} (sampled {v['sampled_mm'][0]:g} x "
                            f"{v['sampled_mm'][1]:g} mm, light scatter {v['scatter_sigma_mm']:g} mm)"])
            continue
        if isinstance(v, (list, tuple)) and len(v) == 2 and all(isinstance(x, (int, float)) for x in v):
            word = "Lightness range the plate shows" if "L" in k else k.replace("_", " ")
            out.append([word, f"{v[0]:.0f}–{v[1]:.0f}" + (" L*" if "L" in k else "")])
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            out.append([k.replace("_", " "), f"{v:.4g}"])
    return out


_LITHO_FIELDS = {"--max": "Thickest (black)", "--min": "Thinnest (white)", "--foot": "Foot depth",
                 "--line-width": "Line width", "--max-speed": "Fastest head speed", "--width": "Width",
                 "--diameter": "Diameter", "--height": "Height", "--frame": "Frame",
                 "--layer-height": "Layer height", "--infill-flow": "Mid-line flow", "--accel": "Printer acceleration", "--gamma": "Gamma",
                 "--attenuation": "Attenuation", "--temp": "Nozzle", "--bed-temp": "Bed",
                 "--curve": "Curve", "--shape": "Shape", "--invert": "Invert"}


def _message(e: BaseException) -> str:
    if isinstance(e, OSError) and not isinstance(e, BulgekitError):
        return f"{e.filename or ''}: {e.strerror or e}"
    return str(e)


# -- HTTP

class _TooBig(Exception):
    """An upload past its limit: its part is removed, the answer says so."""


def _error(status: int, text: str) -> web.Response:
    return web.json_response({"error": text}, status=status)


def make_app(st: Studio, port_ref: dict) -> web.Application:
    """port_ref["port"] is the port the server ended up on (known after binding)."""

    @web.middleware
    async def guard(request: web.Request, handler):
        port = port_ref.get("port")
        allowed = {f"127.0.0.1:{port}", f"localhost:{port}"}
        if request.host not in allowed:
            return _error(403, f"refused: Host {request.host!r} is not this studio")
        origin = request.headers.get("Origin")
        if origin is not None and origin not in {f"http://{h}" for h in allowed}:
            return _error(403, f"refused: request from another origin ({origin})")
        if request.headers.get("Sec-Fetch-Site") in ("cross-site", "same-site"):
            return _error(403, "refused: request from another site")
        if request.path.startswith(("/api/", "/files/")):
            tok = request.headers.get("X-Studio-Token") or request.query.get("t")
            if not tok or not secrets.compare_digest(tok, st.token):
                return _error(403, "refused: no valid studio token (reload the page)")
        resp = await handler(request)
        resp.headers["X-Content-Type-Options"] = "nosniff"
        resp.headers["Cache-Control"] = "no-store"
        return resp

    app = web.Application(middlewares=[guard], client_max_size=4 * MB)
    loop_run = asyncio.get_running_loop

    page = (STATIC / "index.html").read_text(encoding="utf-8")
    # the one inline script, the import map, is allowed by its hash; nothing else inline runs
    imap = re.search(r'<script type="importmap">(.*?)</script>', page, re.S).group(1)
    imap_hash = base64.b64encode(hashlib.sha256(imap.encode()).digest()).decode()
    csp = (f"default-src 'self'; script-src 'self' 'sha256-{imap_hash}'; img-src 'self' data: blob:; "
           "style-src 'self' 'unsafe-inline'; connect-src 'self'; frame-ancestors 'none'")

    async def index(request):
        return web.Response(text=page.replace("__STUDIO_TOKEN__", st.token), content_type="text/html",
                            headers={"Content-Security-Policy": csp})

    async def state(request):
        from ..bulge.mapformat import LAYER_POINTS_MAX
        from ..bulge.strokes import font_names
        return web.json_response({
            "gcode": st.gcode_state(), "assets": st.asset_kinds, "design": st.design,
            "design_gcode": st.design_gcode, "fonts": font_names(),
            "limits": {"gcode_mb": st.limits.gcode_bytes / MB, "asset_mb": st.limits.asset_bytes / MB,
                       "image_megapixels": st.limits.image_pixels / 1e6, "arena": st.limits.arena,
                       "layer_points": LAYER_POINTS_MAX},
            "jobs": [j.json() for j in st.jobs.values() if j.state == "running"],
            "workdir": str(st.workdir), "litho": litho_choices(), "litho_last": st.litho_last,
            "printers": printer_choices()})

    def too_big(name: str, limit: int, what: str, size: int | None = None) -> web.Response:
        hint = "; start it with a larger --max-upload" if what == "G-code" else ""
        told = f"{size / MB:.1f} MB is " if size is not None else ""
        return _error(413, f"{name}: {told}more than the studio takes for {what} ({limit / MB:.0f} MB{hint})")

    def upload_name(request, limit: int, what: str) -> str | web.Response:
        """The uploaded file's name, or the refusal when it has none or says it is too big."""
        name = request.query.get("name", "")
        if not name:
            return _error(400, "the upload has no file name")
        size = request.content_length
        if size is not None and size > limit:
            return too_big(name, limit, what, size)
        return name

    async def upload_gcode(request):
        name = upload_name(request, st.limits.gcode_bytes, "G-code")
        if isinstance(name, web.Response):
            return name
        base = dz.safe_name(name, "part.gcode")
        dest = st.workdir / "gcode" / f"{st.next_id()}-{base}"
        got = 0
        try:                                    # an upload cut off or refused leaves nothing
            with outputs.part(dest) as part, open(part, "wb") as f:
                async for chunk in request.content.iter_chunked(1 << 20):
                    got += len(chunk)
                    if got > st.limits.gcode_bytes:
                        raise _TooBig
                    f.write(chunk)
        except _TooBig:
            return too_big(name, st.limits.gcode_bytes, "G-code")
        job = st.start("open", st.open_upload, dest, name)
        return web.json_response(job.json())

    async def upload_asset(request):
        name = upload_name(request, st.limits.asset_bytes, "a drawing or picture")
        if isinstance(name, web.Response):
            return name
        data = bytearray()
        async for chunk in request.content.iter_chunked(1 << 20):
            data += chunk
            if len(data) > st.limits.asset_bytes:
                return too_big(name, st.limits.asset_bytes, "a drawing or picture")
        try:
            info = await loop_run().run_in_executor(st.worker, st.add_asset, name, bytes(data))
        except (BulgekitError, ValueError, OSError) as e:
            return _error(400, st.user_words(_message(e)))
        return web.json_response(info)

    async def body(request) -> dict:
        try:
            d = await request.json()
        except (json.JSONDecodeError, UnicodeDecodeError):
            raise web.HTTPBadRequest(text=json.dumps({"error": "the request is not JSON"}),
                                     content_type="application/json")
        if not isinstance(d, dict):
            raise web.HTTPBadRequest(text=json.dumps({"error": "expected a JSON object"}),
                                     content_type="application/json")
        return d

    async def preview(request):
        d = await body(request)
        try:
            res = await loop_run().run_in_executor(st.worker, st.preview, d.get("design") or {},
                                                   bool(d.get("check")))
        except (BulgekitError, ValueError, OSError) as e:
            return _error(400, _message(e))
        return web.json_response(res)

    async def export(request):
        d = await body(request)
        return web.json_response(st.start("export", st.export, d.get("design") or {}).json())

    async def placement(request):
        d = await body(request)
        try:
            text = dz.placement_text(d.get("design") or {}, st.assets)
        except (BulgekitError, ValueError) as e:
            return _error(400, _message(e))
        return web.Response(text=text, content_type="application/toml",
                            headers={"Content-Disposition": 'attachment; filename="placement.toml"'})

    async def import_placement(request):
        d = await body(request)
        text, files = d.get("toml"), d.get("files") or {}
        if not isinstance(text, str) or not isinstance(files, dict):
            return _error(400, "expected {toml: text, files: {name: asset}}")
        try:
            res = await loop_run().run_in_executor(st.worker, dz.from_placement, text, files, st.assets,
                                                   st.workdir / "scratch")
        except (BulgekitError, ValueError, OSError) as e:
            return _error(400, st.user_words(_message(e)))
        return web.json_response(res)

    async def job(request):
        j = st.jobs.get(request.match_info["id"])
        if j is None:
            return _error(404, "no such job")
        return web.json_response(j.json())

    async def ports(request):
        try:
            from serial.tools import list_ports
            found = [{"device": p.device, "description": p.description} for p in list_ports.comports()]
        except Exception as e:                      # no serial support on this system
            return web.json_response({"ports": [], "note": str(e)})
        return web.json_response({"ports": found})

    async def send(request):
        d = await body(request)
        litho = "litho" in d                      # a lithophane's file, else the wall tab's export
        port = str(d.get("port") or "").strip()
        if not port:
            return _error(400, "choose the printer's port (e.g. /dev/ttyUSB0)")
        try:
            baud = int(d.get("baud", 115200))
        except (TypeError, ValueError):
            return _error(400, f"baud: expected a whole number, got {d.get('baud')!r}")
        if st.sending.locked():
            return _error(409, "a file is being sent already")
        key = str(d.get("litho" if litho else "export", ""))
        which = str(d.get("which", "litho" if litho else "bulge"))
        j = st.start("send", st.send, key, which, port, baud, litho, thread=True)
        return web.json_response(j.json())

    async def litho(request):
        d = await body(request)
        opts = d.get("options") or {}
        if not isinstance(opts, dict):
            return _error(400, "options: expected an object")
        j = st.start("litho", st.litho, str(d.get("asset", "")), dict(opts), d.get("name"))
        return web.json_response(j.json())

    async def litho_view_data(request):
        made = st.lithos.get(request.match_info["key"])
        if made is None:
            return _error(404, "no such lithophane")
        return web.json_response(made["view"])

    async def files(request):
        area, rest = request.match_info["area"], request.match_info["rest"]
        if area not in ("exports", "litho"):
            raise web.HTTPNotFound()
        base = (st.workdir / area).resolve()
        path = (base / rest).resolve()
        if base not in path.parents or not path.is_file():
            raise web.HTTPNotFound()
        # always an attachment, sandboxed: an uploaded SVG must never run as a page of this origin
        # (an <img> still shows the lithophane's look)
        return web.FileResponse(path, headers={"Content-Disposition": f'attachment; filename="{path.name}"',
                                               "Content-Security-Policy": "sandbox; default-src 'none'"})

    app.router.add_get("/", index)
    app.router.add_static("/static/", STATIC, follow_symlinks=False)
    app.router.add_get("/api/state", state)
    app.router.add_post("/api/gcode", upload_gcode)
    app.router.add_post("/api/asset", upload_asset)
    app.router.add_post("/api/preview", preview)
    app.router.add_post("/api/export", export)
    app.router.add_post("/api/placement", placement)
    app.router.add_post("/api/import", import_placement)
    app.router.add_get("/api/job/{id}", job)
    app.router.add_get("/api/ports", ports)
    app.router.add_post("/api/send", send)
    app.router.add_post("/api/litho", litho)
    app.router.add_get("/api/litho/{key}/view", litho_view_data)
    app.router.add_get("/files/{area}/{rest:.+}", files)
    return app


class Running:
    """A started server (serve()): its address, and stop()."""

    def __init__(self, st: Studio, url: str, loop, runner, thread):
        self.studio, self.url, self._loop, self._runner, self._thread = st, url, loop, runner, thread

    def stop(self):
        fut = asyncio.run_coroutine_threadsafe(self._runner.cleanup(), self._loop)
        fut.result(10)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(10)
        self.studio.worker.shutdown(wait=False, cancel_futures=True)


def serve(st: Studio, port: int = 0) -> Running:
    """Start the server in a thread on 127.0.0.1:port (0: any free port)."""
    check_assets()
    loop = asyncio.new_event_loop()
    port_ref: dict = {}
    app = make_app(st, port_ref)
    runner = web.AppRunner(app, access_log=None)
    ready = threading.Event()
    err: list = []

    def run():
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(runner.setup())
            site = web.TCPSite(runner, "127.0.0.1", port)
            loop.run_until_complete(site.start())
            port_ref["port"] = site._server.sockets[0].getsockname()[1]
        except BaseException as e:
            err.append(e)
            ready.set()
            return
        ready.set()
        loop.run_forever()

    th = threading.Thread(target=run, name="studio-http", daemon=True)
    th.start()
    ready.wait(30)
    if err:
        e = err[0]
        if isinstance(e, OSError):
            raise BulgekitError(f"cannot listen on 127.0.0.1:{port}: {e.strerror or e} "
                                "(another program on that port? use --port N)") from None
        raise e
    return Running(st, f"http://127.0.0.1:{port_ref['port']}/", loop, runner, th)
