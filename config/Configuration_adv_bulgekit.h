/**
 * bulgekit options for Marlin's Configuration_adv.h
 *
 * install-marlin.py appends this block to Configuration_adv.h between
 * "bulgekit:begin config" / "bulgekit:end config" markers (--uninstall takes it
 * out again). It may also be pasted by hand. Every BK_ size, default and limit
 * not set here keeps the value of the core's bulgekit_config.h.
 */

// @section bulgekit

/**
 * Bulge maps (M720, M721, M722)
 *
 * Over-extrusion at chosen points of the outer wall (Takahashi & Miyashita):
 * each outer-wall move that passes a bulge point of the current layer is cut
 * there, the head stops for P ms and the next piece carries E mm of extra
 * filament. The splitting happens in the planner queue; the host's X Y Z and E
 * (M82/M83, G92) are never changed. Maps are uploaded with M721.
 * Needs: a Cartesian or Core machine with G0/G1 lines on the outer wall (G2/G3
 * arcs are not split; the first one in a print gets an echo: notice), one
 * extruder.
 */
#define BULGE_MAP
#if ENABLED(BULGE_MAP)
  /**
   * RAM: the arena plus about 560 bytes is taken from what Marlin's stack has
   * left ("Free Memory" on the boot line). 1024 always works: the host streams
   * a larger map in appends while printing, and the arena must only hold two
   * full layers (910 bytes at 64 points; the sample prints need 208). A larger
   * arena means fewer appends; give the host the same figure
   * (bulgekit annotate --arena N; `bulgekit send` checks it).
   */
  #define BK_MAP_ARENA_BYTES   1024  // (bytes) RAM for the compact map (and the staged upload)
  #define BK_LAYER_POINTS_MAX    64  // Bulge points one layer may hold (decoded working set)
  #define BK_DEFAULT_DWELL_MS   100  // (ms) M720 P at power-on
  #define BK_DEFAULT_EXTRA_E_MM 0.1f // (mm) M720 E at power-on: extra filament per stop
  #define BK_DEFAULT_TOLERANCE_MM 0.25f // (mm) M720 T: how far from a move a point still counts
  #define BK_MAX_DWELL_MS      2000  // (ms) M720 P above this is refused with an Error
  #define BK_MAX_EXTRA_E_MM    1.0f  // (mm) M720 E above this is refused with an Error
#endif

/**
 * Width by feedrate (M723)
 *
 * Constant extruder rate, line width set by the head speed (Jang & Hong 2017):
 * while M723 S1 is in force every extruding G0/G1 is retimed so the extruder
 * turns at the rate set with M723 Q (flow) or R (filament mm/s).
 */
#define WIDTH_BY_FEEDRATE
#if ENABLED(WIDTH_BY_FEEDRATE)
  #define BK_DEFAULT_FILAMENT_DIA_MM 1.75f // (mm) M723 D at power-on
  #define BK_DEFAULT_WIDTH_MIN_SPEED 5.0f  // (mm/s) M723 L: retimed moves never go slower
  #define BK_DEFAULT_WIDTH_MAX_SPEED 150.0f // (mm/s) M723 U: retimed moves never go faster
#endif
