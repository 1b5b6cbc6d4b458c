#!/usr/bin/env python3
"""Install bulgekit into a Marlin 2.1.2.x checkout, or take it out again.

    python3 install-marlin.py PATH            # install (or update)
    python3 install-marlin.py PATH --uninstall
    python3 install-marlin.py PATH --check    # report, change nothing

PATH is the checkout root (holding Marlin/ and, for PlatformIO, ini/) or its
Marlin/ folder. What an install does:

  * copies this repository's Marlin/ files to the same paths in the checkout,
    and the portable core (src/*.h, src/*.cpp) to Marlin/src/feature/bulgekit/core/
    together with config/bulgekit_config.h and a small bulgekit_config.h shim
    that lets Configuration_adv.h override the core's sizes and defaults;
  * inserts hook lines at named anchors in Marlin's sources, each between
    "bulgekit:begin <name>" and "bulgekit:end <name>" marker comments; an anchor
    is a run of whole lines that must occur exactly once, or nothing is written;
  * appends the option block of config/Configuration_adv_bulgekit.h to
    Configuration_adv.h, and feature lines to ini/features.ini if present;
  * records every copied file with its SHA-256 in a manifest.

Running it again gives the same tree (old blocks are replaced, files
refreshed). --uninstall removes the marked blocks (restoring any line a block
replaced), the files in the manifest and the folders it made, and refuses to
delete a copied file that was edited since (unless --force).
Standard library only.
"""

import argparse
import hashlib
import os
import re
import sys

REPO = os.path.dirname(os.path.abspath(__file__))   # this script sits at the checkout's top

TAG = "bulgekit"
CORE_DIR = "Marlin/src/feature/bulgekit/core"
MANIFEST = "Marlin/src/feature/bulgekit/bulgekit-manifest.txt"
VERSION_H = "Marlin/src/inc/Version.h"
SUPPORTED = re.compile(r'^2\.1\.2(\.\d+)?$')

SHIM = """\
// bulgekit core configuration inside Marlin (written by bulgekit's install-marlin.py).
// Marlin's Configuration.h and Configuration_adv.h come first, so any BK_ value
// set there wins; the core's own file then fills in the rest.
#pragma once
#include "../../../inc/MarlinConfigPre.h"
#define BK_REPLY_SERIAL 1  // replies go out through Marlin's serial port (bulgekit.cpp)
#define BK_PLAN_STATS 0    // the firmware never reads the stop statistics (every board, not only AVR)
#include "bulgekit_config_defaults.h"
"""


class InstallError(Exception):
    pass


class Edit:
    """One marked block in a Marlin file.

    mode 'before' / 'after': insert text before the first / after the last
    anchor line; 'replace': the anchor lines are replaced by text and kept in
    the block as 'bulgekit:was' comments; 'append': at the end of the file.
    """

    def __init__(self, path, name, mode, anchor, text, comment="//", optional=False, regex=None, alts=()):
        self.path, self.name, self.mode = path, name, mode
        self.anchor = anchor.split("\n") if anchor else []
        # the same place as other 2.1.2.x releases spell it, tried in order
        # when the anchor itself is not found
        self.alts = [a.split("\n") for a in alts]
        self.text = text
        self.comment = comment
        self.optional = optional  # the whole file may be absent (ini/features.ini)
        # regex: the anchor is one line matching this pattern (anchor holds an
        # example line); text may use its groups as \\1, \\2 ...
        self.regex = re.compile(regex) if regex else None


# ---- hooks for Marlin 2.1.2.x ------------------------------------------------------

EDITS = [
    Edit("Marlin/src/gcode/gcode.cpp", "mcodes", "before",
         "      #if ENABLED(GCODE_MACROS)",
         """\
      #if ENABLED(BULGE_MAP)
        case 720: M720(); break;                                  // M720: Bulge map settings
        case 721: M721(); break;                                  // M721: Bulge map upload
        case 722: M722(); break;                                  // M722: Outer-wall marker
      #endif
      #if ENABLED(WIDTH_BY_FEEDRATE)
        case 723: M723(); break;                                  // M723: Width by feedrate
      #endif
"""),
    Edit("Marlin/src/gcode/gcode.h", "decls", "before",
         "  static void T(const int8_t tool_index);",
         """\
  #if ENABLED(BULGE_MAP)
    static void M720();
    static void M720_report(const bool forReplay=true);
    static void M721();
    static void M722();
  #endif
  #if ENABLED(WIDTH_BY_FEEDRATE)
    static void M723();
    static void M723_report(const bool forReplay=true);
  #endif
"""),
    Edit("Marlin/src/gcode/motion/G0_G1.cpp", "include", "after",
         '#include "../../sd/cardreader.h"',
         '#include "../../feature/bulgekit/bulgekit.h"\n'),
    Edit("Marlin/src/gcode/motion/G0_G1.cpp", "line", "before",
         "    prepare_line_to_destination();\n  #endif\n\n  #ifdef G0_FEEDRATE",
         """\
    #if HAS_BULGEKIT
      if (!bulgekit.line_to_destination())  // bulge splits and width mode queue the move themselves
    #endif
"""),
    # Arcs bypass G0_G1(): plan_arc() feeds its segments to the planner directly.
    # Not split or retimed; the hook reports that once per print (BulgeKit::arc_notice).
    Edit("Marlin/src/gcode/motion/G2_G3.cpp", "arc-include", "after",
         '#include "../../module/temperature.h"',
         '#include "../../feature/bulgekit/bulgekit.h"\n'),
    Edit("Marlin/src/gcode/motion/G2_G3.cpp", "arc-notice", "before",
         "    plan_arc(destination, arc_offset, clockwise, circles_to_do);",
         """\
    #if HAS_BULGEKIT
      bulgekit.arc_notice();  // the arc is neither split nor retimed: say so once per print
    #endif
"""),
    Edit("Marlin/src/module/planner.h", "flag-bit", "after",
         "  OPTARG(LASER_POWER_SYNC, BLOCK_BIT_LASER_PWR)",
         """\

  // Hold the axes for a time (Planner::buffer_dwell, timed by the stepper ISR)
  OPTARG(BULGE_MAP, BLOCK_BIT_DWELL)
"""),
    Edit("Marlin/src/module/planner.h", "flag-field", "after",
         "        bool sync_laser_pwr:1;\n      #endif",
         """\

      #if ENABLED(BULGE_MAP)
        bool dwell:1;
      #endif
"""),
    Edit("Marlin/src/module/planner.h", "is-move", "replace",
         "  bool is_move() { return !(is_sync() || is_page()); }",
         """\
  #if ENABLED(BULGE_MAP)
    bool is_dwell() { return flag.dwell; }
    bool is_move() { return !(is_sync() || is_page() || is_dwell()); }
  #else
    bool is_move() { return !(is_sync() || is_page()); }
  #endif
"""),
    Edit("Marlin/src/module/planner.h", "buffer-dwell", "after",
         "      static void buffer_sync_block(const BlockFlagBit flag=BLOCK_BIT_SYNC_POSITION);",
         """\

      #if ENABLED(BULGE_MAP)
        // A stop at rest and, for ms > 0, a hold of ms milliseconds (bulgekit.cpp)
        static void buffer_dwell(const uint16_t ms);
      #endif
"""),
    Edit("Marlin/src/module/stepper.cpp", "dwell-counter", "before",
         "uint32_t Stepper::block_phase_isr() {",
         """\
#if ENABLED(BULGE_MAP)
  /**
   * Dwell block timing. The hold is measured from the last step before the bulge
   * point to the first step after it: it starts in the ISR call that made the
   * last step, runs in chunks of at most 1ms (a quick stop still ends it at once),
   * and the block after it takes its first step BK_DWELL_LEAD after the hold
   * instead of one full start interval (8.3ms at MINIMAL_STEP_RATE) later.
   */
  #define BK_DWELL_LEAD ((STEPPER_TIMER_RATE) / 2000UL)  // 500µs: more than loading the next block takes
  // A compare period is compare + 1 ticks: AVR CTC (reset at OCR1A), STM32
  // (ARR = compare), STM32F1/maple (ARR = compare), LPC176x (reset on MR0
  // match). HAL/LINUX's timer waits exactly the compare.
  #if defined(__AVR__) || defined(HAL_STM32) || defined(__STM32F1__) || defined(TARGET_STM32F1) || defined(TARGET_LPC1768)
    #define BK_TICK_EXTRA 1UL
  #else
    #define BK_TICK_EXTRA 0UL
  #endif
  static uint32_t bk_dwell_left;  // Timer ticks the current dwell block still holds
  static bool bk_dwell_ended;     // The next block's first step closes a hold
  static uint32_t bk_dwell_chunk() {
    const uint32_t c = _MIN(bk_dwell_left, (STEPPER_TIMER_RATE) / 1000UL);
    bk_dwell_left -= c;
    return c > BK_TICK_EXTRA ? c - BK_TICK_EXTRA : 0;
  }
#endif

"""),
    Edit("Marlin/src/module/stepper.cpp", "dwell-hold", "after",
         "  // If no queued movements, just wait 1ms for the next block\n"
         "  uint32_t interval = (STEPPER_TIMER_RATE) / 1000UL;",
         """\

  #if ENABLED(BULGE_MAP)
    // Dwell block: hold on; once the ticks are used up the block is discarded below
    if (current_block && current_block->is_dwell() && bk_dwell_left) return bk_dwell_chunk();
  #endif
"""),
    Edit("Marlin/src/module/stepper.cpp", "dwell-start", "after",
         "        // Try to get a new block\n"
         "        if (!(current_block = planner.get_current_block()))\n"
         "          return interval; // No more queued movements!\n"
         "      }",
         """\

      #if ENABLED(BULGE_MAP)
        if (current_block->is_dwell()) {          // Start holding: no steps, no direction change
          step_event_count = step_events_completed = 0;
          const uint32_t hold = current_block->step_event_count * ((STEPPER_TIMER_RATE) / 1000UL),
                         lead = BK_DWELL_LEAD + BK_TICK_EXTRA;
          bk_dwell_left = hold > lead ? hold - lead : 0;
          bk_dwell_ended = true;
          return bk_dwell_chunk();
        }
      #endif
"""),
    Edit("Marlin/src/module/stepper.cpp", "dwell-lead", "after",
         "      // Calculate the initial timer interval\n"
         "      interval = calc_timer_interval(current_block->initial_rate << oversampling_factor, steps_per_isr);\n"
         "      acceleration_time += interval;",
         """\

      #if ENABLED(BULGE_MAP)
        // After a dwell the first step comes at once; the ramp goes on as if the
        // full start interval had passed, so the rest of the block is unchanged
        if (bk_dwell_ended) { bk_dwell_ended = false; NOMORE(interval, BK_DWELL_LEAD); }
      #endif
"""),
    Edit("Marlin/src/gcode/host/M115.cpp", "caps", "after",
         '    cap_line(F("CONFIG_EXPORT"), ENABLED(CONFIGURATION_EMBEDDING));',
         """\

    // bulgekit: bulge maps (M720-M722), width by feedrate (M723); with both
    // off the block is empty and M115 is stock
    #if ANY(BULGE_MAP, WIDTH_BY_FEEDRATE)
      cap_line(F("BULGE_MAP"), ENABLED(BULGE_MAP));
      cap_line(F("WIDTH_BY_FEEDRATE"), ENABLED(WIDTH_BY_FEEDRATE));
    #endif
"""),
    Edit("Marlin/src/module/settings.cpp", "report", "before",
         "    //\n    // Model predictive control\n    //\n    TERN_(MPCTEMP, gcode.M306_report(forReplay));",
         """\
    #if ANY(BULGE_MAP, WIDTH_BY_FEEDRATE)
      //
      // bulgekit
      //
      TERN_(BULGE_MAP, gcode.M720_report(forReplay));
      TERN_(WIDTH_BY_FEEDRATE, gcode.M723_report(forReplay));
    #endif

"""),
    # EEPROM: M720/M723 parameters (see BulgeKit::settings_save). Marlin changes
    # EEPROM_VERSION whenever the layout changes; with bulgekit the letter
    # becomes B ("V88" -> "B88"), which no stock version string can equal, so
    # neither firmware reads the other's data (both fall back to defaults).
    Edit("Marlin/src/module/settings.cpp", "eeprom-version", "replace",
         '#define EEPROM_VERSION "V88"',
         """\
#define EEPROM_VERSION TERN(BULGE_MAP, "B\\1", TERN(WIDTH_BY_FEEDRATE, "B\\1", "V\\1")) // bulgekit adds settings
""", regex=r'#define EEPROM_VERSION "V(\d+)"'),
    Edit("Marlin/src/module/settings.cpp", "eeprom-include", "after",
         '#include "../MarlinCore.h"',
         '#include "../feature/bulgekit/bulgekit.h"\n'),
    Edit("Marlin/src/module/settings.cpp", "eeprom-fields", "after",
         "  #if ENABLED(MPCTEMP)\n"
         "    MPC_t mpc_constants[HOTENDS];                       // M306\n"
         "  #endif",
         """\

  //
  // bulgekit: M720 / M723 parameters (see bulgekit.h)
  //
  #if ENABLED(BULGE_MAP)
    BulgeKit::settings_t bulgekit_m720;               // M720 P E T
  #endif
  #if ENABLED(WIDTH_BY_FEEDRATE)
    BulgeKit::settings_t bulgekit_m723;               // M723 Q|R D H L U
  #endif
"""),
    Edit("Marlin/src/module/settings.cpp", "eeprom-save", "after",
         "    #if ENABLED(MPCTEMP)\n"
         "      HOTEND_LOOP()\n"
         "        EEPROM_WRITE(thermalManager.temp_hotend[e].mpc);\n"
         "    #endif",
         alts=["    #if ENABLED(MPCTEMP)\n"            # 2.1.2.1 names it "constants"
               "      HOTEND_LOOP()\n"
               "        EEPROM_WRITE(thermalManager.temp_hotend[e].constants);\n"
               "    #endif"],
         text=
         """\

    //
    // bulgekit
    //
    #if ENABLED(BULGE_MAP)
    {
      _FIELD_TEST(bulgekit_m720);
      BulgeKit::settings_t line;
      BulgeKit::settings_save(720, line);
      EEPROM_WRITE(line);
    }
    #endif
    #if ENABLED(WIDTH_BY_FEEDRATE)
    {
      _FIELD_TEST(bulgekit_m723);
      BulgeKit::settings_t line;
      BulgeKit::settings_save(723, line);
      EEPROM_WRITE(line);
    }
    #endif
"""),
    Edit("Marlin/src/module/settings.cpp", "eeprom-load", "after",
         "      #if ENABLED(MPCTEMP)\n"
         "      {\n"
         "        HOTEND_LOOP()\n"
         "          EEPROM_READ(thermalManager.temp_hotend[e].mpc);\n"
         "      }\n"
         "      #endif",
         alts=["      #if ENABLED(MPCTEMP)\n"          # 2.1.2.1 names it "constants"
               "      {\n"
               "        HOTEND_LOOP()\n"
               "          EEPROM_READ(thermalManager.temp_hotend[e].constants);\n"
               "      }\n"
               "      #endif"],
         text=
         """\

      //
      // bulgekit
      //
      #if ENABLED(BULGE_MAP)
      {
        _FIELD_TEST(bulgekit_m720);
        BulgeKit::settings_t line;
        EEPROM_READ(line);
        if (!validating) BulgeKit::settings_load(720, line);
      }
      #endif
      #if ENABLED(WIDTH_BY_FEEDRATE)
      {
        _FIELD_TEST(bulgekit_m723);
        BulgeKit::settings_t line;
        EEPROM_READ(line);
        if (!validating) BulgeKit::settings_load(723, line);
      }
      #endif
"""),
    Edit("Marlin/src/module/settings.cpp", "eeprom-reset", "after",
         "  TERN_(DWIN_LCD_PROUI, DWIN_SetDataDefaults());",
         """\

  //
  // bulgekit: M720 / M723 defaults, modes off (the map stays)
  //
  #if HAS_BULGEKIT
    BulgeKit::settings_reset();
  #endif
"""),
    Edit("ini/features.ini", "features", "after",
         "GCODE_MACROS                           = build_src_filter=+<src/gcode/feature/macro>",
         """\
BULGE_MAP                              = build_src_filter=+<src/feature/bulgekit> +<src/gcode/feature/bulgekit>
WIDTH_BY_FEEDRATE                      = build_src_filter=+<src/feature/bulgekit> +<src/gcode/feature/bulgekit>
""", comment="#", optional=True),
]


def config_edit():
    with open(os.path.join(REPO, "config", "Configuration_adv_bulgekit.h"), encoding="utf-8") as f:
        text = f.read()
    if not text.endswith("\n"):
        text += "\n"
    return Edit("Marlin/Configuration_adv.h", "config", "append", None, "\n" + text)


# ---- files to copy -----------------------------------------------------------------

def files_to_copy():
    """(destination path relative to the checkout root, bytes) for every file."""
    out = []
    mroot = os.path.join(REPO, "Marlin")
    for dirpath, dirnames, filenames in os.walk(mroot):
        dirnames.sort()
        for fn in sorted(filenames):
            src = os.path.join(dirpath, fn)
            rel = os.path.relpath(src, REPO).replace(os.sep, "/")
            with open(src, "rb") as f:
                out.append((rel, f.read()))
    srcdir = os.path.join(REPO, "src")
    core = sorted(fn for fn in os.listdir(srcdir) if fn.endswith((".h", ".cpp")))
    if not core:
        raise InstallError("no core sources in %s" % srcdir)
    for fn in core:
        if fn == "bulgekit_config.h":
            raise InstallError("src/bulgekit_config.h would clash with the installed shim")
        with open(os.path.join(srcdir, fn), "rb") as f:
            out.append((CORE_DIR + "/" + fn, f.read()))
    with open(os.path.join(REPO, "config", "bulgekit_config.h"), "rb") as f:
        out.append((CORE_DIR + "/bulgekit_config_defaults.h", f.read()))
    out.append((CORE_DIR + "/bulgekit_config.h", SHIM.encode("utf-8")))
    return out


def sha256(data):
    return hashlib.sha256(data).hexdigest()


# ---- text blocks ---------------------------------------------------------------------

def split_lines(text):
    """Lines without their ends, and the file's line end ('\\n' or '\\r\\n')."""
    eol = "\r\n" if "\r\n" in text else "\n"
    lines = text.split("\n")
    if lines and lines[-1] == "":
        lines.pop()
        final_eol = True
    else:
        final_eol = False
    return [l[:-1] if l.endswith("\r") else l for l in lines], eol, final_eol


def join_lines(lines, eol, final_eol):
    return eol.join(lines) + (eol if final_eol and lines else "")


def marker_re(comment, word):
    return re.compile(r"^(\s*)" + re.escape(comment) + " " + TAG + ":" + word + r" (\S+)")


def remove_blocks(lines, comment, path):
    """Drops every marked block, putting back the lines a 'replace' block held."""
    begin, end = marker_re(comment, "begin"), marker_re(comment, "end")
    was = re.compile(r"^\s*" + re.escape(comment) + " " + TAG + r":was \|(.*)$")
    out, i, removed = [], 0, 0
    while i < len(lines):
        m = begin.match(lines[i])
        if not m:
            if end.match(lines[i]):
                raise InstallError("%s:%d: '%s:end' without a begin marker" % (path, i + 1, TAG))
            out.append(lines[i])
            i += 1
            continue
        name, start = m.group(2), i
        i += 1
        while i < len(lines):
            e = end.match(lines[i])
            if e:
                if e.group(2) != name:
                    raise InstallError("%s:%d: block '%s' ends with '%s'" % (path, i + 1, name, e.group(2)))
                break
            w = was.match(lines[i])
            if w:
                out.append(w.group(1))
            i += 1
        else:
            raise InstallError("%s:%d: block '%s' has no end marker" % (path, start + 1, name))
        i += 1
        removed += 1
    return out, removed


def find_anchor(lines, anchor, regex=None):
    """Where the anchor lines stand. Indentation and trailing blanks are not
    compared: releases of 2.1.2.x nest the same code at different depths."""
    if regex:
        return [i for i, l in enumerate(lines) if regex.fullmatch(l)]
    n = len(anchor)
    want = [a.strip() for a in anchor]
    return [i for i in range(len(lines) - n + 1) if [l.strip() for l in lines[i:i + n]] == want]


def reindent(text, shift):
    """text with every non-blank line moved right by shift columns (left if
    negative, never past its first character)."""
    out = []
    for l in text.split("\n"):
        if not l.strip() or shift == 0:
            out.append(l)
        elif shift > 0:
            out.append(" " * shift + l)
        else:
            lead = len(l) - len(l.lstrip(" "))
            out.append(l[min(lead, -shift):])
    return "\n".join(out)


def block_lines(edit, indent, replaced):
    c = edit.comment
    body = edit.text.split("\n")
    if body and body[-1] == "":
        body.pop()
    out = ["%s%s %s:begin %s" % (indent, c, TAG, edit.name)]
    out += ["%s%s %s:was |%s" % (indent, c, TAG, l) for l in replaced]
    out += body
    out.append("%s%s %s:end %s" % (indent, c, TAG, edit.name))
    return out


def apply_edits(lines, edits, path):
    for ed in edits:
        if ed.mode == "append":
            lines = lines + block_lines(ed, "", [])
            continue
        anchor = ed.anchor
        hits = find_anchor(lines, anchor, ed.regex)
        for alt in ed.alts:
            if hits:
                break
            anchor, hits = alt, find_anchor(lines, alt)
        if len(hits) != 1:
            shown = ("a line matching %s, e.g.\n    " % ed.regex.pattern if ed.regex else "") + "\n    ".join(ed.anchor)
            what = "not found" if not hits else "found %d times (must be unique)" % len(hits)
            raise InstallError("%s: anchor '%s' %s; expected the line(s):\n    %s\n"
                               "This Marlin tree differs from 2.1.2.x; nothing was changed."
                               % (path, ed.name, what, shown))
        i, n = hits[0], len(anchor)
        found = lines[i:i + n]
        indent = re.match(r"\s*", found[0]).group(0)
        if ed.regex:
            ed = Edit(ed.path, ed.name, ed.mode, None, ed.regex.fullmatch(found[0]).expand(ed.text), ed.comment)
        elif anchor:
            # the hook's lines follow the anchor's depth in this tree
            shift = len(indent) - len(re.match(r"\s*", anchor[0]).group(0))
            if shift:
                ed = Edit(ed.path, ed.name, ed.mode, "\n".join(anchor), reindent(ed.text, shift),
                          ed.comment, ed.optional)
        if ed.mode == "before":
            lines = lines[:i] + block_lines(ed, indent, []) + lines[i:]
        elif ed.mode == "after":
            lines = lines[:i + n] + block_lines(ed, indent, []) + lines[i + n:]
        elif ed.mode == "replace":
            lines = lines[:i] + block_lines(ed, indent, found) + lines[i + n:]
        else:
            raise InstallError("unknown edit mode %r" % ed.mode)
    return lines


# ---- the checkout ----------------------------------------------------------------------

def locate(path):
    path = os.path.abspath(path)
    if os.path.isfile(os.path.join(path, VERSION_H)):
        return path
    if os.path.isfile(os.path.join(path, "src", "inc", "Version.h")) and os.path.basename(path) == "Marlin":
        return os.path.dirname(path)
    raise InstallError("%s: not a Marlin checkout (no %s)" % (path, VERSION_H))


def marlin_version(root):
    with open(os.path.join(root, VERSION_H), encoding="utf-8", errors="replace") as f:
        text = f.read()
    m = re.search(r'^\s*#\s*define\s+SHORT_BUILD_VERSION\s+"([^"]*)"', text, re.M)
    if not m:
        raise InstallError("%s: no SHORT_BUILD_VERSION" % VERSION_H)
    return m.group(1)


def read_text(root, rel):
    with open(os.path.join(root, rel), encoding="utf-8", newline="") as f:
        return f.read()


def write_bytes(root, rel, data):
    full = os.path.join(root, rel)
    with open(full, "wb") as f:
        f.write(data)


def read_manifest(root):
    full = os.path.join(root, MANIFEST)
    if not os.path.isfile(full):
        return None
    files, dirs = [], []
    with open(full, encoding="utf-8") as f:
        for n, line in enumerate(f, 1):
            line = line.rstrip("\n")
            if not line or line.startswith("#"):
                continue
            parts = line.split(" ", 2)
            if parts[0] == "file" and len(parts) == 3:
                files.append((parts[2], parts[1]))
            elif parts[0] == "dir" and len(parts) == 2:
                dirs.append(parts[1])
            else:
                raise InstallError("%s:%d: unreadable manifest line" % (MANIFEST, n))
    return files, dirs


def edits_by_file():
    grouped = {}
    for ed in EDITS + [config_edit()]:
        grouped.setdefault(ed.path, []).append(ed)
    return grouped


def plan_edits(root, install):
    """New text for every file whose marked blocks change: {rel: (old, new)}."""
    changes, notes = {}, []
    for rel, edits in edits_by_file().items():
        full = os.path.join(root, rel)
        if not os.path.isfile(full):
            if edits[0].optional:
                if install:
                    notes.append("%s not present: skipped (only PlatformIO builds need it)" % rel)
                continue
            if install:
                raise InstallError("%s: file missing; nothing was changed" % rel)
            continue
        old = read_text(root, rel)
        lines, eol, final_eol = split_lines(old)
        lines, _ = remove_blocks(lines, edits[0].comment, rel)
        if install:
            lines = apply_edits(lines, edits, rel)
        new = join_lines(lines, eol, final_eol)
        if new != old:
            changes[rel] = (old, new)
    return changes, notes


def install(root, check_only=False, any_version=False, out=print):
    version = marlin_version(root)
    if not SUPPORTED.match(version):
        msg = "%s: Marlin %s; bulgekit's hooks are made for 2.1.2.x" % (VERSION_H, version)
        if not any_version:
            raise InstallError(msg + " (--any-version tries anyway; every anchor is still checked)")
        out("warning: " + msg)
    changes, notes = plan_edits(root, True)  # raises before anything is written
    copies = files_to_copy()
    old_manifest = read_manifest(root)
    new_dirs = []
    for rel, _ in copies:
        d = os.path.dirname(rel)
        chain = []
        while d and not os.path.isdir(os.path.join(root, d)):
            chain.append(d)
            d = os.path.dirname(d)
        for d in reversed(chain):
            if d not in new_dirs:
                new_dirs.append(d)
    dirs = list(old_manifest[1]) if old_manifest else []
    dirs += [d for d in new_dirs if d not in dirs]
    stale = []
    if old_manifest:
        wanted = {rel for rel, _ in copies}
        stale = [rel for rel, _ in old_manifest[0] if rel not in wanted]
    copy_changes = []
    for rel, data in copies:
        full = os.path.join(root, rel)
        if not os.path.isfile(full):
            copy_changes.append(rel)
        else:
            with open(full, "rb") as f:
                if f.read() != data:
                    copy_changes.append(rel)
    for note in notes:
        out(note)
    if check_only:
        out("Marlin %s: %d file(s) to patch, %d to copy, %d stale to remove"
            % (version, len(changes), len(copy_changes), len(stale)))
        for rel in sorted(changes):
            out("  patch " + rel)
        for rel in copy_changes:
            out("  copy  " + rel)
        return bool(changes or copy_changes or stale)
    for d in new_dirs:
        os.makedirs(os.path.join(root, d), exist_ok=True)
    for rel, data in copies:
        if rel in copy_changes:
            write_bytes(root, rel, data)
    for rel in stale:
        full = os.path.join(root, rel)
        if os.path.isfile(full):
            os.remove(full)
    for rel, (_, new) in sorted(changes.items()):
        write_bytes(root, rel, new.encode("utf-8"))
    lines = ["# bulgekit install manifest: install-marlin.py --uninstall removes these",
             "# Marlin " + version]
    lines += ["dir " + d for d in dirs]
    lines += ["file %s %s" % (sha256(data), rel) for rel, data in copies]
    manifest = ("\n".join(lines) + "\n").encode("utf-8")
    write_bytes(root, MANIFEST, manifest)
    out("bulgekit installed into Marlin %s: %d file(s) patched, %d copied (%d unchanged)"
        % (version, len(changes), len(copy_changes), len(copies) - len(copy_changes)))
    return True


def uninstall(root, force=False, out=print):
    changes, _ = plan_edits(root, False)
    manifest = read_manifest(root)
    files, dirs = manifest if manifest else ([], [])
    edited = []
    for rel, digest in files:
        full = os.path.join(root, rel)
        if os.path.isfile(full):
            with open(full, "rb") as f:
                if sha256(f.read()) != digest:
                    edited.append(rel)
    if edited and not force:
        raise InstallError("edited since install (keep them with a copy, or pass --force):\n  "
                           + "\n  ".join(edited) + "\nnothing was changed")
    if not changes and not files:
        out("bulgekit is not installed here; nothing to do")
        return False
    for rel, (_, new) in sorted(changes.items()):
        write_bytes(root, rel, new.encode("utf-8"))
    removed = 0
    for rel, _ in files:
        full = os.path.join(root, rel)
        if os.path.isfile(full):
            os.remove(full)
            removed += 1
    mfull = os.path.join(root, MANIFEST)
    if os.path.isfile(mfull):
        os.remove(mfull)
    for d in sorted(dirs, key=lambda p: p.count("/"), reverse=True):
        full = os.path.join(root, d)
        if os.path.isdir(full) and not os.listdir(full):
            os.rmdir(full)
    out("bulgekit removed: %d file(s) restored, %d copied file(s) deleted" % (len(changes), removed))
    return True


def main(argv=None):
    ap = argparse.ArgumentParser(description="Install bulgekit into a Marlin 2.1.2.x checkout.")
    ap.add_argument("marlin", help="checkout root (with Marlin/) or its Marlin/ folder")
    ap.add_argument("--uninstall", action="store_true", help="remove exactly what an install added")
    ap.add_argument("--check", action="store_true", help="report what an install would change")
    ap.add_argument("--force", action="store_true", help="uninstall even copied files edited since")
    ap.add_argument("--any-version", action="store_true", help="do not require Marlin 2.1.2.x")
    args = ap.parse_args(argv)
    try:
        root = locate(args.marlin)
        if args.uninstall:
            uninstall(root, force=args.force)
        else:
            install(root, check_only=args.check, any_version=args.any_version)
    except InstallError as e:
        print("install-marlin: error: %s" % e, file=sys.stderr)
        return 1
    except OSError as e:
        print("install-marlin: error: %s" % e, file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
