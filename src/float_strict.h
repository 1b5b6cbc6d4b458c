// The same float results on every target: no fused multiply-add in the core.
//
// A compiler may turn a * b + c into one fused operation where the FPU has one
// (Cortex-M4F, x86 with FMA): one rounding instead of two. The results then
// differ from the host's reference planner (host/bulgekit/fallback.py, plain
// float32 steps) in the last bit, and at the edge of the tolerance or the
// minimum piece that decides a stop: on a Cortex-M4F, test_planner_streams
// found a move whose two points merged into one 200 ms stop instead of two.
// Include last, in the core's .cpp files only (the pragma holds for the rest
// of the file). Targets without fused operations (AVR, Cortex-M3) are left
// alone: GCC does not inline across differing optimize options, so an
// unconditional pragma would change the AVR build.
#ifndef BK_FLOAT_STRICT_H
#define BK_FLOAT_STRICT_H

#if defined(__FP_FAST_FMAF) || defined(__ARM_FEATURE_FMA) || defined(__FMA__)
#if defined(__clang__)
#pragma STDC FP_CONTRACT OFF
#elif defined(__GNUC__)
#pragma GCC optimize("fp-contract=off")
#endif
#endif

#endif  // BK_FLOAT_STRICT_H
