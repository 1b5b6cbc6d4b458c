/**
 * bulgekit for Marlin: the adapter between Marlin and the portable core.
 *
 * The core (core/, copied from bulgekit's src/ by install-marlin.py) is
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

  // Ends a core reply printed through r (see core/reply_text.h): the last
  // line's newline, if anything was printed.
  static void end_reply(const bk::ReplyText &r) { if (!r.empty()) SERIAL_EOL(); }

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
   * Settings in EEPROM (hooks in settings.cpp): the values of M720 P E T and
   * M723 Q|R D H L U. Loading checks each one as the typed command would
   * (the core's restore()), so a stored value can never bypass a limit: a
   * refused set prints its Error: and the values stay as they were. The S
   * switches are not stored: the G-code that needs a mode turns it on (the
   * host's annotate writes M720 S1), so a normal print after power-on is never
   * retimed or split.
   */
  struct settings_t {
    uint8_t kind;   // M723: 0 no target, 1 Q, 2 R (unused for M720)
    float v[5];     // M720: P E T; M723: Q|R D H L U
  };
  static void settings_save(const uint16_t code, settings_t &s);
  static void settings_load(const uint16_t code, const settings_t &s);
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
