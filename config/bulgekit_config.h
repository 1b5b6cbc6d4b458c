// bulgekit feature configuration: defaults, hard limits and per-board sizes.
// The portable core (src/) includes only this file for its sizes, so the same
// numbers hold in the unit tests, the simulator and the Marlin build. A Marlin
// build may override any of them from Configuration_adv.h (see config/).
#ifndef BULGEKIT_CONFIG_H
#define BULGEKIT_CONFIG_H

// ---- sizes (RAM) --------------------------------------------------------------
// The map arena: layer records held at once (and an upload's staging). The host
// streams a larger map in appends; that always fits when the arena holds two of
// the largest records the format allows (the layer in print and the next one:
// 7 * BK_LAYER_POINTS_MAX + 7 bytes each, 910 B in all for 64 points; checked
// in bulge_map.h). The sample prints need at most 208 B (tools/arena_window.py).
#ifndef BK_MAP_ARENA_BYTES
#if defined(__AVR__)
#define BK_MAP_ARENA_BYTES 1024  // an ATmega2560 has 8 KiB of RAM in all
#else
#define BK_MAP_ARENA_BYTES 2048
#endif
#endif
#ifndef BK_LAYER_POINTS_MAX
#define BK_LAYER_POINTS_MAX 64  // decoded working set: bulge points of one layer
#endif

// ---- bulge defaults (Takahashi & Miyashita: 0.4 mm nozzle, 0.3 mm layers) ----------
#ifndef BK_DEFAULT_DWELL_MS
#define BK_DEFAULT_DWELL_MS 100
#endif
#ifndef BK_DEFAULT_EXTRA_E_MM
#define BK_DEFAULT_EXTRA_E_MM 0.1f
#endif
#ifndef BK_DEFAULT_TOLERANCE_MM
#define BK_DEFAULT_TOLERANCE_MM 0.25f
#endif
// Pieces shorter than this are not cut off: the point dwells at the move end.
#ifndef BK_MIN_PIECE_MM
#define BK_MIN_PIECE_MM 0.1f
#endif

// ---- bulge hard limits (a request beyond them is an Error:, never clipped) ---------
#ifndef BK_MAX_DWELL_MS
#define BK_MAX_DWELL_MS 2000
#endif
#ifndef BK_MAX_EXTRA_E_MM
#define BK_MAX_EXTRA_E_MM 1.0f
#endif
#ifndef BK_MAX_TOLERANCE_MM
#define BK_MAX_TOLERANCE_MM 2.0f
#endif

// ---- width by feedrate ------------------------------------------------------------
#ifndef BK_DEFAULT_FILAMENT_DIA_MM
#define BK_DEFAULT_FILAMENT_DIA_MM 1.75f
#endif
#ifndef BK_DEFAULT_WIDTH_MIN_SPEED
#define BK_DEFAULT_WIDTH_MIN_SPEED 5.0f  // mm/s, L
#endif
#ifndef BK_DEFAULT_WIDTH_MAX_SPEED
#define BK_DEFAULT_WIDTH_MAX_SPEED 150.0f  // mm/s, U
#endif

// ---- width mode (M723): hard limits (a request beyond them is an Error:) ----------
#ifndef BK_WIDTH_MAX_FLOW_MM3S
#define BK_WIDTH_MAX_FLOW_MM3S 100.0f  // Q; well above what FDM hotends melt
#endif
#ifndef BK_WIDTH_MAX_E_RATE
#define BK_WIDTH_MAX_E_RATE 50.0f  // r, mm/s of filament, from R or from Q and D
#endif
#ifndef BK_WIDTH_MIN_FILAMENT_DIA
#define BK_WIDTH_MIN_FILAMENT_DIA 1.0f
#endif
#ifndef BK_WIDTH_MAX_FILAMENT_DIA
#define BK_WIDTH_MAX_FILAMENT_DIA 3.5f
#endif
#ifndef BK_WIDTH_MAX_LAYER_MM
#define BK_WIDTH_MAX_LAYER_MM 2.0f  // H
#endif
#ifndef BK_WIDTH_MAX_LINE_MM
#define BK_WIDTH_MAX_LINE_MM 5.0f  // W of one move
#endif
#ifndef BK_WIDTH_MIN_SPEED_LIMIT
#define BK_WIDTH_MIN_SPEED_LIMIT 0.1f  // lowest L accepted, mm/s
#endif
#ifndef BK_WIDTH_MAX_SPEED_LIMIT
#define BK_WIDTH_MAX_SPEED_LIMIT 1000.0f  // highest U accepted, mm/s
#endif

// ---- planner (src/bulge_planner, src/move_state) ----------------------------------
// Cuts one ActionList carries (a line to a stop + the stop: 2 actions each, plus
// the final line); a move passing more stops is continued with
// BulgePlanner::plan_more(). Points that share a stop need no cut of their own.
// 1 keeps the list at 3 actions (62 bytes on AVR).
#ifndef BK_PLAN_HITS_MAX
#define BK_PLAN_HITS_MAX 1
#endif
// Feedrate before the first F word (Marlin's power-on value), mm/min.
#ifndef BK_MOVE_DEFAULT_FEED_MM_MIN
#define BK_MOVE_DEFAULT_FEED_MM_MIN 1500.0f
#endif
// Room for one M720/M722 reply line ("echo:..." or "Error:..."), with the NUL,
// where replies go into a buffer (tests, tools; the firmware prints them as
// they are written): the longest is "Error:M720 P->=1000000 not in [0.000..2000.000]" (47).
#ifndef BK_PLAN_REPLY_MAX
#define BK_PLAN_REPLY_MAX 48
#endif

// ---- replies (src/reply_text) ---------------------------------------------------------
// 1: the M-code replies are printed by the firmware's serial port (the Marlin
// install sets it; the adapter implements ReplyText). 0: into a buffer (tests, tools).
#ifndef BK_REPLY_SERIAL
#define BK_REPLY_SERIAL 0
#endif

// ---- map codec (src/bulge_map, src/map_upload: M721) -------------------------------
// Base32 characters one "M721 O<offset> D<base32>" line may carry (40 bytes):
// with "N<n> " and "*<cs>" the line stays within Marlin's 96-byte buffer.
#ifndef BK_M721_CHUNK_CHARS_MAX
#define BK_M721_CHUNK_CHARS_MAX 64
#endif
// Room for one M721 reply (up to two lines), with the NUL (a buffer in tests and tools).
#ifndef BK_M721_REPLY_BYTES
#define BK_M721_REPLY_BYTES 128
#endif

#endif  // BULGEKIT_CONFIG_H
