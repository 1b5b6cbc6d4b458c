// bktest: a small Unity-style test library of our own.
//
// The same test file builds for the host (g++) and for the simulated ATmega2560
// (avr-gcc 5.4, run in simavr by tools/sim/bksim). Output is one line per case in
// the form PlatformIO's Unity reader understands,
//     <file>:<line>:<name>:PASS
//     <file>:<line>:<name>:FAIL: <message>
// and a closing line "N passed, N failed".
//
// A failed assertion ends the current test case (setjmp/longjmp, as Unity does).
// On AVR every string the macros pass lives in flash (PSTR), so large suites do
// not eat the 8 KiB of RAM; MESSAGE arguments must therefore be string literals.
#ifndef BKTEST_H
#define BKTEST_H

#include <stddef.h>
#include <stdint.h>

#ifdef __AVR__
#include <avr/pgmspace.h>
#define BKT_S(s) PSTR(s)
#else
#define BKT_S(s) (s)
#endif

#ifdef __cplusplus
extern "C" {
#endif

// --- runner -------------------------------------------------------------------
void bkt_begin(void);
// Prints the closing line; returns 0, or 65 if any case failed (main's exit
// status). On AVR it ends the simulation (cli + sleep) and does not return.
int bkt_end(void);
void bkt_run(void (*fn)(void), const char *name, const char *file, int line);
void bkt_ignore(const char *file, int line, const char *msg);

// --- assertion back ends (file/msg are flash strings on AVR) ------------------
void bkt_assert(int cond, const char *file, int line, const char *expr, const char *msg);
void bkt_assert_int(int32_t exp, int32_t act, const char *file, int line, const char *msg);
void bkt_assert_uint(uint32_t exp, uint32_t act, int hex, const char *file, int line, const char *msg);
void bkt_assert_cmp_int(int32_t thr, int32_t act, int op, const char *file, int line, const char *msg);
void bkt_assert_float(double delta, double exp, double act, const char *file, int line, const char *msg);
void bkt_assert_string(const char *exp, const char *act, const char *file, int line, const char *msg);
void bkt_assert_memory(const void *exp, const void *act, size_t len, const char *file, int line, const char *msg);
void bkt_assert_null(const void *p, int want_null, const char *file, int line, const char *msg);

// --- output helpers usable from tests and benchmarks --------------------------
void bkt_putc(char c);
void bkt_puts(const char *s);    // RAM string
void bkt_puts_P(const char *s);  // flash string on AVR, RAM elsewhere
void bkt_put_int(int32_t v);
void bkt_put_uint(uint32_t v);
void bkt_put_float(double v, int decimals);
#define TEST_PRINT(literal) bkt_puts_P(BKT_S(literal))

// --- benchmark markers ---------------------------------------------------------
// On AVR, BEGIN/END write 1/2 to GPIOR0; the simulator harness counts the
// cycles between them and hands the count back through reads of GPIOR1.
// On the host they read a monotonic clock and the unit is nanoseconds; on
// Cortex-M in QEMU they count instructions (bktest.cpp, tools/sim/bkqemu).
#ifdef __AVR__
#include <avr/io.h>
#define BKT_BENCH_BEGIN() do { __asm__ __volatile__("" ::: "memory"); GPIOR0 = 1; } while (0)
#define BKT_BENCH_END()   do { GPIOR0 = 2; __asm__ __volatile__("" ::: "memory"); } while (0)
#else
void bkt_bench_mark(int which);
#define BKT_BENCH_BEGIN() bkt_bench_mark(1)
#define BKT_BENCH_END()   bkt_bench_mark(2)
#endif
uint32_t bkt_bench_last(void);    // cycles (AVR), instructions (Cortex-M in QEMU) or ns (host)
const char *bkt_bench_unit(void); // "cycles", "insns" or "ns" (RAM string)
int bkt_on_avr(void);

#ifdef __cplusplus
}
#endif

// --- Unity-compatible macro names ----------------------------------------------
#define UNITY_BEGIN() bkt_begin()
#define UNITY_END() bkt_end()
#define RUN_TEST(fn) bkt_run(fn, BKT_S(#fn), BKT_S(__FILE__), __LINE__)
#define TEST_IGNORE() bkt_ignore(BKT_S(__FILE__), __LINE__, BKT_S(""))
#define TEST_IGNORE_MESSAGE(m) bkt_ignore(BKT_S(__FILE__), __LINE__, BKT_S(m))
#define TEST_MESSAGE(m) do { bkt_puts_P(BKT_S(m)); bkt_putc('\n'); } while (0)

#define TEST_FAIL_MESSAGE(m) bkt_assert(0, BKT_S(__FILE__), __LINE__, BKT_S("fail"), BKT_S(m))
#define TEST_FAIL() TEST_FAIL_MESSAGE("")
#define TEST_ASSERT_MESSAGE(c, m) bkt_assert(!!(c), BKT_S(__FILE__), __LINE__, BKT_S(#c), BKT_S(m))
#define TEST_ASSERT(c) TEST_ASSERT_MESSAGE(c, "")
#define TEST_ASSERT_TRUE_MESSAGE(c, m) TEST_ASSERT_MESSAGE(c, m)
#define TEST_ASSERT_TRUE(c) TEST_ASSERT_MESSAGE(c, "")
#define TEST_ASSERT_FALSE_MESSAGE(c, m) bkt_assert(!(c), BKT_S(__FILE__), __LINE__, BKT_S("!(" #c ")"), BKT_S(m))
#define TEST_ASSERT_FALSE(c) TEST_ASSERT_FALSE_MESSAGE(c, "")
#define TEST_ASSERT_NULL(p) bkt_assert_null((const void *)(p), 1, BKT_S(__FILE__), __LINE__, BKT_S(#p))
#define TEST_ASSERT_NOT_NULL(p) bkt_assert_null((const void *)(p), 0, BKT_S(__FILE__), __LINE__, BKT_S(#p))

#define TEST_ASSERT_EQUAL_INT_MESSAGE(e, a, m) bkt_assert_int((int32_t)(e), (int32_t)(a), BKT_S(__FILE__), __LINE__, BKT_S(m))
#define TEST_ASSERT_EQUAL_INT(e, a) TEST_ASSERT_EQUAL_INT_MESSAGE(e, a, "")
#define TEST_ASSERT_EQUAL(e, a) TEST_ASSERT_EQUAL_INT(e, a)
#define TEST_ASSERT_EQUAL_INT8(e, a) TEST_ASSERT_EQUAL_INT(e, a)
#define TEST_ASSERT_EQUAL_INT16(e, a) TEST_ASSERT_EQUAL_INT(e, a)
#define TEST_ASSERT_EQUAL_INT32(e, a) TEST_ASSERT_EQUAL_INT(e, a)
#define TEST_ASSERT_EQUAL_UINT_MESSAGE(e, a, m) bkt_assert_uint((uint32_t)(e), (uint32_t)(a), 0, BKT_S(__FILE__), __LINE__, BKT_S(m))
#define TEST_ASSERT_EQUAL_UINT(e, a) TEST_ASSERT_EQUAL_UINT_MESSAGE(e, a, "")
#define TEST_ASSERT_EQUAL_UINT8(e, a) TEST_ASSERT_EQUAL_UINT(e, a)
#define TEST_ASSERT_EQUAL_UINT16(e, a) TEST_ASSERT_EQUAL_UINT(e, a)
#define TEST_ASSERT_EQUAL_UINT32(e, a) TEST_ASSERT_EQUAL_UINT(e, a)
#define TEST_ASSERT_EQUAL_size_t(e, a) TEST_ASSERT_EQUAL_UINT(e, a)
#define TEST_ASSERT_EQUAL_HEX8(e, a) bkt_assert_uint((uint32_t)(e), (uint32_t)(a), 1, BKT_S(__FILE__), __LINE__, BKT_S(""))
#define TEST_ASSERT_EQUAL_HEX16(e, a) TEST_ASSERT_EQUAL_HEX8(e, a)
#define TEST_ASSERT_EQUAL_HEX32(e, a) TEST_ASSERT_EQUAL_HEX8(e, a)

// op: 0 <, 1 <=, 2 >, 3 >=  (Unity order: threshold first, then actual)
#define TEST_ASSERT_LESS_THAN_INT(t, a) bkt_assert_cmp_int((int32_t)(t), (int32_t)(a), 0, BKT_S(__FILE__), __LINE__, BKT_S(""))
#define TEST_ASSERT_LESS_OR_EQUAL_INT(t, a) bkt_assert_cmp_int((int32_t)(t), (int32_t)(a), 1, BKT_S(__FILE__), __LINE__, BKT_S(""))
#define TEST_ASSERT_GREATER_THAN_INT(t, a) bkt_assert_cmp_int((int32_t)(t), (int32_t)(a), 2, BKT_S(__FILE__), __LINE__, BKT_S(""))
#define TEST_ASSERT_GREATER_OR_EQUAL_INT(t, a) bkt_assert_cmp_int((int32_t)(t), (int32_t)(a), 3, BKT_S(__FILE__), __LINE__, BKT_S(""))
#define TEST_ASSERT_LESS_THAN(t, a) TEST_ASSERT_LESS_THAN_INT(t, a)
#define TEST_ASSERT_LESS_OR_EQUAL(t, a) TEST_ASSERT_LESS_OR_EQUAL_INT(t, a)
#define TEST_ASSERT_GREATER_THAN(t, a) TEST_ASSERT_GREATER_THAN_INT(t, a)
#define TEST_ASSERT_GREATER_OR_EQUAL(t, a) TEST_ASSERT_GREATER_OR_EQUAL_INT(t, a)

#define TEST_ASSERT_FLOAT_WITHIN_MESSAGE(d, e, a, m) bkt_assert_float((double)(d), (double)(e), (double)(a), BKT_S(__FILE__), __LINE__, BKT_S(m))
#define TEST_ASSERT_FLOAT_WITHIN(d, e, a) TEST_ASSERT_FLOAT_WITHIN_MESSAGE(d, e, a, "")
#define TEST_ASSERT_DOUBLE_WITHIN(d, e, a) TEST_ASSERT_FLOAT_WITHIN(d, e, a)
// Unity's default: within 1e-5 of the expected value, relative.
#define TEST_ASSERT_EQUAL_FLOAT(e, a) bkt_assert_float(-1.0, (double)(e), (double)(a), BKT_S(__FILE__), __LINE__, BKT_S(""))

#define TEST_ASSERT_EQUAL_STRING_MESSAGE(e, a, m) bkt_assert_string((e), (a), BKT_S(__FILE__), __LINE__, BKT_S(m))
#define TEST_ASSERT_EQUAL_STRING(e, a) TEST_ASSERT_EQUAL_STRING_MESSAGE(e, a, "")
#define TEST_ASSERT_EQUAL_MEMORY_MESSAGE(e, a, n, m) bkt_assert_memory((e), (a), (n), BKT_S(__FILE__), __LINE__, BKT_S(m))
#define TEST_ASSERT_EQUAL_MEMORY(e, a, n) TEST_ASSERT_EQUAL_MEMORY_MESSAGE(e, a, n, "")
#define TEST_ASSERT_EQUAL_UINT8_ARRAY(e, a, n) TEST_ASSERT_EQUAL_MEMORY(e, a, (size_t)(n))
#define TEST_ASSERT_EQUAL_HEX8_ARRAY(e, a, n) TEST_ASSERT_EQUAL_MEMORY(e, a, (size_t)(n))

// Unity calls these around every test case; a suite may define them or not.
#ifdef __cplusplus
extern "C" {
#endif
void setUp(void);
void tearDown(void);
#ifdef __cplusplus
}
#endif

#endif  // BKTEST_H
