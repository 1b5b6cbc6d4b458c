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

  BulgeKit();  // attaches the planner to the store (static members, same translation unit)

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
  #if ENABLED(BULGE_MAP)
    static bk::ActionList actions;  // static: keeps ~140 bytes off the G1 call stack
  #endif
};

extern BulgeKit bulgekit;

#endif // HAS_BULGEKIT
