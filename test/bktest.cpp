// bktest runner and assertion back ends. See bktest.h.
#include "bktest.h"

#include <setjmp.h>
#include <string.h>

#ifdef __AVR__
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <stdlib.h>
#else
#include <stdio.h>
#include <time.h>
#endif

extern "C" {
__attribute__((weak)) void setUp(void) {}
__attribute__((weak)) void tearDown(void) {}
}

static jmp_buf bkt_abort;
static uint16_t bkt_passed, bkt_failed, bkt_ignored;
static uint8_t bkt_case_state;  // 0 running, 1 failed, 2 ignored
static const char *bkt_cur_name;

// --- raw output -----------------------------------------------------------------
#ifdef __AVR__
// USART0, polled, 115200 baud (U2X, UBRR 16). The simulator harness sets UDRE0
// when the transmitter is enabled (simavr 1.6 does not).
static void bkt_uart_init(void) {
  UCSR0A = _BV(U2X0);
  UBRR0 = 16;
  UCSR0B = _BV(TXEN0);
  UCSR0C = _BV(UCSZ01) | _BV(UCSZ00);
}
void bkt_putc(char c) {
  if (c == '\n') bkt_putc('\r');
  loop_until_bit_is_set(UCSR0A, UDRE0);
  UDR0 = (uint8_t)c;
}
void bkt_puts_P(const char *s) {
  char c;
  while ((c = (char)pgm_read_byte(s++))) bkt_putc(c);
}
static char bkt_flash_char(const char *s, size_t i) { return (char)pgm_read_byte(s + i); }
#else
void bkt_putc(char c) { fputc(c, stdout); }
void bkt_puts_P(const char *s) { fputs(s, stdout); }
static char bkt_flash_char(const char *s, size_t i) { return s[i]; }
#endif

void bkt_puts(const char *s) {
  while (*s) bkt_putc(*s++);
}

void bkt_put_uint(uint32_t v) {
  char buf[11];
  uint8_t n = 0;
  do {
    buf[n++] = (char)('0' + v % 10);
    v /= 10;
  } while (v);
  while (n) bkt_putc(buf[--n]);
}

void bkt_put_int(int32_t v) {
  if (v < 0) {
    bkt_putc('-');
    bkt_put_uint((uint32_t)0 - (uint32_t)v);
  } else {
    bkt_put_uint((uint32_t)v);
  }
}

static void bkt_put_hex(uint32_t v) {
  static const char digits[] = "0123456789ABCDEF";
  bkt_putc('0');
  bkt_putc('x');
  int shift = 28;
  while (shift > 0 && ((v >> shift) & 0xF) == 0) shift -= 4;
  for (; shift >= 0; shift -= 4) bkt_putc(digits[(v >> shift) & 0xF]);
}

// Fixed-point float printer: enough for test messages and benchmark tables
// without pulling printf's float support into the AVR image.
void bkt_put_float(double v, int decimals) {
  if (v != v) {
    bkt_puts("nan");
    return;
  }
  if (v < 0) {
    bkt_putc('-');
    v = -v;
  }
  if (v > 4.0e9) {
    bkt_puts("big");
    return;
  }
  double scale = 1;
  for (int i = 0; i < decimals; i++) scale *= 10;
  double r = v * scale + 0.5;
  uint32_t ip = (uint32_t)(r / scale);
  uint32_t fp = (uint32_t)(r - (double)ip * scale);
  bkt_put_uint(ip);
  if (decimals > 0) {
    bkt_putc('.');
    uint32_t div = (uint32_t)(scale / 10);
    for (int i = 0; i < decimals; i++) {
      bkt_putc((char)('0' + (fp / div) % 10));
      div = div > 1 ? div / 10 : 1;
    }
  }
}

// --- case bookkeeping -------------------------------------------------------------
static void bkt_head(const char *file, int line) {
  bkt_puts_P(file);
  bkt_putc(':');
  bkt_put_int(line);
  bkt_putc(':');
  bkt_puts_P(bkt_cur_name);
  bkt_putc(':');
}

// Prints "<file>:<line>:<name>:FAIL: " and leaves the line open for the detail.
static void bkt_fail_head(const char *file, int line) {
  bkt_head(file, line);
  bkt_puts("FAIL: ");
}

static void bkt_fail_tail(const char *msg) {
  if (msg && bkt_flash_char(msg, 0)) {
    bkt_puts(" - ");
    bkt_puts_P(msg);
  }
  bkt_putc('\n');
  bkt_case_state = 1;
  longjmp(bkt_abort, 1);
}

void bkt_begin(void) {
#ifdef __AVR__
  bkt_uart_init();
#else
  setvbuf(stdout, NULL, _IOLBF, 0);
#endif
  bkt_passed = bkt_failed = bkt_ignored = 0;
}

int bkt_end(void) {
  bkt_putc('\n');
  bkt_put_uint(bkt_passed);
  bkt_puts(" passed, ");
  bkt_put_uint(bkt_failed);
  bkt_puts(" failed");
  if (bkt_ignored) {
    bkt_puts(", ");
    bkt_put_uint(bkt_ignored);
    bkt_puts(" skipped");
  }
  bkt_putc('\n');
  // PlatformIO's Unity reader closes a suite on this line.
  bkt_put_uint((uint32_t)bkt_passed + bkt_failed + bkt_ignored);
  bkt_puts(" Tests ");
  bkt_put_uint(bkt_failed);
  bkt_puts(" Failures ");
  bkt_put_uint(bkt_ignored);
  bkt_puts(" Ignored\n");
  bkt_puts(bkt_failed ? "FAIL\n" : "OK\n");
#ifdef __AVR__
  loop_until_bit_is_set(UCSR0A, UDRE0);
  // Ends the simulation: simavr stops on sleep with interrupts off.
  cli();
  sleep_enable();
  sleep_cpu();
  for (;;) {
  }
#else
  fflush(stdout);
  // 65 rather than the failure count: PlatformIO reports small exit codes as
  // signal names ("SIGHUP"), which would mislead.
  return bkt_failed ? 65 : 0;
#endif
}

void bkt_run(void (*fn)(void), const char *name, const char *file, int line) {
  bkt_cur_name = name;
  bkt_case_state = 0;
  if (setjmp(bkt_abort) == 0) {
    setUp();
    fn();
  }
  if (setjmp(bkt_abort) == 0) tearDown();
  if (bkt_case_state == 0) {
    bkt_head(file, line);
    bkt_puts("PASS\n");
    bkt_passed++;
  } else if (bkt_case_state == 1) {
    bkt_failed++;
  } else {
    bkt_ignored++;
  }
}

void bkt_ignore(const char *file, int line, const char *msg) {
  bkt_head(file, line);
  bkt_puts("IGNORE");
  if (msg && bkt_flash_char(msg, 0)) {
    bkt_puts(": ");
    bkt_puts_P(msg);
  }
  bkt_putc('\n');
  bkt_case_state = 2;
  longjmp(bkt_abort, 1);
}

// --- assertions --------------------------------------------------------------------
void bkt_assert(int cond, const char *file, int line, const char *expr, const char *msg) {
  if (cond) return;
  bkt_fail_head(file, line);
  bkt_puts("Expression ");
  bkt_puts_P(expr);
  bkt_puts(" is false");
  bkt_fail_tail(msg);
}

void bkt_assert_int(int32_t exp, int32_t act, const char *file, int line, const char *msg) {
  if (exp == act) return;
  bkt_fail_head(file, line);
  bkt_puts("Expected ");
  bkt_put_int(exp);
  bkt_puts(" Was ");
  bkt_put_int(act);
  bkt_fail_tail(msg);
}

void bkt_assert_uint(uint32_t exp, uint32_t act, int hex, const char *file, int line, const char *msg) {
  if (exp == act) return;
  bkt_fail_head(file, line);
  bkt_puts("Expected ");
  if (hex) bkt_put_hex(exp); else bkt_put_uint(exp);
  bkt_puts(" Was ");
  if (hex) bkt_put_hex(act); else bkt_put_uint(act);
  bkt_fail_tail(msg);
}

void bkt_assert_cmp_int(int32_t thr, int32_t act, int op, const char *file, int line, const char *msg) {
  int ok = op == 0 ? act < thr : op == 1 ? act <= thr : op == 2 ? act > thr : act >= thr;
  if (ok) return;
  static const char *const ops[] = {"less than ", "less or equal to ", "greater than ", "greater or equal to "};
  bkt_fail_head(file, line);
  bkt_puts("Expected ");
  bkt_puts(ops[op & 3]);
  bkt_put_int(thr);
  bkt_puts(" Was ");
  bkt_put_int(act);
  bkt_fail_tail(msg);
}

void bkt_assert_float(double delta, double exp, double act, const char *file, int line, const char *msg) {
  if (delta < 0) {  // Unity's TEST_ASSERT_EQUAL_FLOAT: relative 1e-5
    delta = (exp < 0 ? -exp : exp) * 1e-5;
    if (delta < 1e-30) delta = 1e-30;
  }
  double diff = exp - act;
  if (diff < 0) diff = -diff;
  if (diff <= delta) return;  // NaN fails here too
  bkt_fail_head(file, line);
  bkt_puts("Expected ");
  bkt_put_float(exp, 6);
  bkt_puts(" Was ");
  bkt_put_float(act, 6);
  bkt_puts(" (within ");
  bkt_put_float(delta, 6);
  bkt_putc(')');
  bkt_fail_tail(msg);
}

void bkt_assert_string(const char *exp, const char *act, const char *file, int line, const char *msg) {
  if (exp && act && strcmp(exp, act) == 0) return;
  bkt_fail_head(file, line);
  bkt_puts("Expected '");
  bkt_puts(exp ? exp : "(null)");
  bkt_puts("' Was '");
  bkt_puts(act ? act : "(null)");
  bkt_putc('\'');
  bkt_fail_tail(msg);
}

void bkt_assert_memory(const void *exp, const void *act, size_t len, const char *file, int line, const char *msg) {
  const uint8_t *e = (const uint8_t *)exp, *a = (const uint8_t *)act;
  for (size_t i = 0; i < len; i++) {
    if (e[i] == a[i]) continue;
    bkt_fail_head(file, line);
    bkt_puts("Memory mismatch at byte ");
    bkt_put_uint((uint32_t)i);
    bkt_puts(": expected ");
    bkt_put_hex(e[i]);
    bkt_puts(" was ");
    bkt_put_hex(a[i]);
    bkt_fail_tail(msg);
  }
}

void bkt_assert_null(const void *p, int want_null, const char *file, int line, const char *expr) {
  if ((p == NULL) == (want_null != 0)) return;
  bkt_fail_head(file, line);
  bkt_puts_P(expr);
  bkt_puts(want_null ? " was not NULL" : " was NULL");
  bkt_fail_tail(NULL);
}

// --- benchmark markers ----------------------------------------------------------------
#ifdef __AVR__
uint32_t bkt_bench_last(void) {
  // The harness answers four reads of GPIOR1 with the count, low byte first.
  uint32_t v = 0;
  for (uint8_t i = 0; i < 4; i++) v |= (uint32_t)GPIOR1 << (8 * i);
  return v;
}
const char *bkt_bench_unit(void) { return "cycles"; }
int bkt_on_avr(void) { return 1; }
#elif defined(__arm__)
// Bare metal in QEMU (tools/sim/bkqemu): -icount shift=0 makes the virtual
// clock advance 1 ns per instruction, and SysTick, on the MPS2 boards' 25 MHz
// CPU clock, counts down one tick per 40 ns: 40 instructions per tick. The
// count is QEMU's, not a real core's cycles (no wait states, no pipeline).
#define BKT_SYST_CSR (*(volatile uint32_t *)0xE000E010u)
#define BKT_SYST_RVR (*(volatile uint32_t *)0xE000E014u)
#define BKT_SYST_CVR (*(volatile uint32_t *)0xE000E018u)
static const uint32_t BKT_INSNS_PER_TICK = 40;
static uint32_t bkt_t0, bkt_dt;
void bkt_bench_mark(int which) {
  if (!(BKT_SYST_CSR & 1u)) {
    BKT_SYST_RVR = 0xFFFFFFu;  // 24 bits: 671 M instructions before it wraps
    BKT_SYST_CVR = 0;
    BKT_SYST_CSR = 5u;  // enabled, CPU clock, no interrupt
  }
  const uint32_t now = BKT_SYST_CVR;  // counts down
  if (which == 1) bkt_t0 = now;
  else bkt_dt = ((bkt_t0 - now) & 0xFFFFFFu) * BKT_INSNS_PER_TICK;
}
uint32_t bkt_bench_last(void) { return bkt_dt; }
const char *bkt_bench_unit(void) { return "insns"; }
int bkt_on_avr(void) { return 0; }
#else
static uint64_t bkt_t0, bkt_dt;
static uint64_t bkt_now_ns(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}
void bkt_bench_mark(int which) {
  if (which == 1) bkt_t0 = bkt_now_ns();
  else bkt_dt = bkt_now_ns() - bkt_t0;
}
uint32_t bkt_bench_last(void) { return bkt_dt > 0xFFFFFFFFu ? 0xFFFFFFFFu : (uint32_t)bkt_dt; }
const char *bkt_bench_unit(void) { return "ns"; }
int bkt_on_avr(void) { return 0; }
#endif
