/**
 * bulgekit for Marlin: configuration checks (included by bulgekit.h, so they run
 * in every translation unit that uses the feature).
 */
#pragma once

#if ENABLED(BULGE_MAP)
  #if !HAS_EXTRUDERS
    #error "BULGE_MAP needs an extruder."
  #elif HAS_MULTI_EXTRUDER
    #error "BULGE_MAP supports one extruder (EXTRUDERS 1)."
  #elif IS_KINEMATIC
    #error "BULGE_MAP is for Cartesian and Core machines (DELTA/SCARA/POLARGRAPH are not supported)."
  #elif HAS_I_AXIS
    #error "BULGE_MAP supports X Y Z E machines only (no I/J/K/U/V/W axes)."
  #elif ENABLED(DIRECT_STEPPING)
    #error "BULGE_MAP cannot be combined with DIRECT_STEPPING."
  #elif ENABLED(LASER_FEATURE)
    #error "BULGE_MAP cannot be combined with LASER_FEATURE."
  #elif ENABLED(MIXING_EXTRUDER)
    #error "BULGE_MAP cannot be combined with MIXING_EXTRUDER."
  #endif
  #if defined(BK_DEFAULT_DWELL_MS) && defined(BK_MAX_DWELL_MS) && BK_DEFAULT_DWELL_MS > BK_MAX_DWELL_MS
    #error "BK_DEFAULT_DWELL_MS must not exceed BK_MAX_DWELL_MS."
  #endif
  #if defined(BK_MAX_DWELL_MS) && BK_MAX_DWELL_MS > 60000
    #error "BK_MAX_DWELL_MS must be 60000 or less (the dwell block counts 16-bit milliseconds)."
  #endif
  #if defined(BK_MAP_ARENA_BYTES) && defined(__AVR__) && BK_MAP_ARENA_BYTES > 4096
    #error "BK_MAP_ARENA_BYTES above 4096 leaves too little RAM on an 8-bit AVR."
  #endif
  #if defined(BK_MAP_ARENA_BYTES) && BK_MAP_ARENA_BYTES < 64
    #error "BK_MAP_ARENA_BYTES must be at least 64."
  #endif
#endif

#if ENABLED(WIDTH_BY_FEEDRATE)
  #if !HAS_EXTRUDERS
    #error "WIDTH_BY_FEEDRATE needs an extruder."
  #elif HAS_MULTI_EXTRUDER
    #error "WIDTH_BY_FEEDRATE supports one extruder (EXTRUDERS 1)."
  #elif IS_KINEMATIC
    #error "WIDTH_BY_FEEDRATE is for Cartesian and Core machines."
  #elif HAS_W_AXIS
    #error "WIDTH_BY_FEEDRATE uses the W word for line width; it cannot be used with a W axis."
  #endif
#endif

// Float settings cannot be compared by the preprocessor; these run after the
// core's bulgekit_config.h has filled in every value not set in Configuration_adv.h.
#ifdef BK_DEFAULT_WIDTH_MIN_SPEED
  static_assert(BK_DEFAULT_WIDTH_MIN_SPEED > 0 && BK_DEFAULT_WIDTH_MIN_SPEED <= BK_DEFAULT_WIDTH_MAX_SPEED,
                "BK_DEFAULT_WIDTH_MIN_SPEED must be > 0 and not exceed BK_DEFAULT_WIDTH_MAX_SPEED.");
#endif
#ifdef BK_DEFAULT_EXTRA_E_MM
  static_assert(BK_DEFAULT_EXTRA_E_MM >= 0 && BK_DEFAULT_EXTRA_E_MM <= BK_MAX_EXTRA_E_MM,
                "BK_DEFAULT_EXTRA_E_MM must be 0..BK_MAX_EXTRA_E_MM.");
#endif
#ifdef BK_DEFAULT_TOLERANCE_MM
  static_assert(BK_DEFAULT_TOLERANCE_MM > 0 && BK_DEFAULT_TOLERANCE_MM <= BK_MAX_TOLERANCE_MM,
                "BK_DEFAULT_TOLERANCE_MM must be > 0 and not exceed BK_MAX_TOLERANCE_MM.");
#endif
