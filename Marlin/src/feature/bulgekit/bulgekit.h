/**
 * bulgekit for Marlin: the adapter between Marlin and the portable core.
 *
 * The core (core/, copied from bulgekit's src/ by tools/marlin_install.py) is
 * plain C++ that knows nothing of Marlin. This adapter owns its objects (the
 * map store, the M721 upload, the bulge planner, width mode) and turns what the
 * core decides into Marlin motion:
 *   - a LINE piece  -> destination + prepare_line_to_destination()
 *                      (so leveling, software endstops, M220/M221 still apply)
 *   - a DWELL       -> Planner::buffer_dwell(ms): a queued hold block that the
 *                      stepper ISR times, with rest-to-rest junctions around it
 *   - extra filament -> extruded by the pieces, then the planner's E is re-based
 *                      on the host's E (an internal E offset; the host never
 *                      sees its E change)
 * See docs/marlin-integration.md in the bulgekit repository.
 */
#pragma once

#include "../../inc/MarlinConfigPre.h"

#define HAS_BULGEKIT ANY(BULGE_MAP, WIDTH_BY_FEEDRATE)

// Bytes of one stored settings line (EEPROM, see BulgeKit::settings_save)
#define BK_SETTINGS_LINE 64

#if HAS_BULGEKIT

#include "core/gcode_args.h"
#if ENABLED(BULGE_MAP)
  #include "core/bulge_map.h"
  #include "core/map_upload.h"
  #include "core/bulge_planner.h"
#endif
#if ENABLED(WIDTH_BY_FEEDRATE)
  #include "core/width_mode.h"
#endif

#include "SanityCheck.h"

class BulgeKit {
 public:
  /**
   * G0/G1 hook, called after get_destination_from_command(). Returns true if it
   * queued (or refused, with an Error: line) the move itself; false means "not
   * mine": the caller runs prepare_line_to_destination() exactly as stock.
   */
  static bool line_to_destination();

  // Prints a core reply: zero or more lines separated by '\n'.
  static void print_reply(const char *text);

  // Parses a fixed command kept in flash ("M720") from a copy in buf, which must
  // outlive args (its words point into it). A literal would be kept in RAM on AVR.
  static bool parse_P(bk::GcodeArgs &args, char (&buf)[8], PGM_P text);

  /**
   * G2/G3 hook (G2_G3.cpp, before plan_arc()). Marlin cuts an arc into segments
   * that go straight to the planner and never reach line_to_destination(), so an
   * arc is neither split at bulge points nor retimed by width mode. When a mode
   * would have acted on an extruding arc (M720 S2; M720 S1 inside M722 S1; M723
   * S1), one echo: line says so, once per mode until re-armed by arc_rearm().
   */
  static void arc_notice();
  /**
   * Re-arm the arc notice for the next print: M720 or M723 with parameters
   * (accepted), a committed full map or M721 X, M502. Appends (streamed layers
   * during a print) and M722 markers do not re-arm.
   */
  enum : uint8_t { ARC_BULGE = 1, ARC_WIDTH = 2 };
  static void arc_rearm(const uint8_t which) { arc_told &= ~which; }

  BulgeKit();  // attaches the planner to the store (static members, same translation unit)

  /**
   * Settings in EEPROM (hooks in settings.cpp). M720 and M723 keep their
   * parameters as the command line M503 prints, without the S switch:
   * "M720 P100 E0.100 T0.250", "M723 Q3.200 D1.750 H0.200 L5.000 U60.000".
   * Loading runs that line through the same parser and checks as a typed
   * command, so a stored value can never bypass a limit (a refused line
   * prints its Error: and the values stay as they were). The S switches are
   * not stored: the G-code that needs a mode turns it on (the host's annotate
   * writes M720 S1), so a normal print after power-on is never retimed or split.
   */
  typedef char settings_line_t[BK_SETTINGS_LINE];
  static void settings_save(const uint16_t code, settings_line_t &line);
  static void settings_load(const uint16_t code, settings_line_t &line);
  static void settings_reset();  // M502 / no valid EEPROM: defaults, switches off; the map stays

  #if ENABLED(BULGE_MAP)
    static bk::MapStore store;
    static bk::MapUpload upload;
    static bk::BulgePlanner bulge;  // not "planner": that name is Marlin's
    static float e_offset_total;  // extra filament extruded since power-on, mm (host never saw it)
    static void map_replaced() { bulge.map_changed(); }
  #endif

  #if ENABLED(WIDTH_BY_FEEDRATE)
    static bk::WidthMode width;
  #endif

 private:
  static uint8_t arc_told;  // ARC_BULGE / ARC_WIDTH: that notice was printed since the last re-arm
  #if ENABLED(BULGE_MAP)
    static bk::ActionList actions;  // static: keeps it (56 bytes) off the G1 call stack
  #endif
};

extern BulgeKit bulgekit;

#endif // HAS_BULGEKIT
