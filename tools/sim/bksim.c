/*
 * bksim — the bulgekit simulator harness: runs an AVR ELF in libsimavr (Debian's
 * simavr 1.6) as fast as the host allows and
 *   - copies UART0 output to stdout byte for byte (CR dropped unless --raw),
 *   - feeds UART0 input from a file or stdin at the configured baud rate
 *     (optionally one line per "ok", as Marlin hosts send),
 *   - or (--pty) bridges UART0 to a pseudo-terminal, so a host program such as
 *     `bulgekit send` or Pronterface talks to the simulated board,
 *   - ends a run of a program that never stops (Marlin) when it has gone idle
 *     (--idle-timeout), or on SIGINT/SIGTERM, with its output and trace complete,
 *   - records port pin edges with cycle timestamps (for step traces),
 *   - enforces a cycle cap so a hung program fails in seconds,
 *   - counts cycles between benchmark markers: the program writes 1 then 2 to
 *     GPIOR0; the count is printed on stderr with --markers and returned to the
 *     program on four reads of GPIOR1 (low byte first).
 *
 * Exit status: 0 = the program stopped by itself (cli + sleep), --settle or
 * --idle-timeout ended the run and, unless --no-test, bktest's closing line
 * said 0 failed. 65 = tests failed, 66 = no closing line, 70 = cycle cap
 * reached, 71 = crash, 72 = usage or I/O. (Codes above 64 so PlatformIO does
 * not report them as signal numbers.) 128 + N = ended by signal N (SIGINT 130,
 * SIGTERM 143), after writing out the output and the trace.
 */
#include <errno.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <fcntl.h>
#include <pty.h>
#include <signal.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <simavr/avr_ioport.h>
#include <simavr/avr_uart.h>
#include <simavr/sim_avr.h>
#include <simavr/sim_elf.h>
#include <simavr/sim_io.h>
#include <simavr/sim_irq.h>

/* ATmega2560 data-space addresses (I/O address + 0x20). */
#define ADDR_GPIOR0 0x3E
#define ADDR_GPIOR1 0x4A
#define ADDR_UCSR0A 0xC0
#define ADDR_UCSR0B 0xC1
#define ADDR_UBRR0L 0xC4
#define ADDR_UBRR0H 0xC5
#define RXC0_BIT 7
#define U2X0_BIT 1
#define UDRE0_BIT 5
#define TXEN0_BIT 3
#define RXEN0_BIT 4

static avr_t *avr;

/* ---- activity, for --idle-timeout ------------------------------------------------
 * The last simulated cycle at which a UART byte went either way or a traced pin
 * changed. The wall-clock side is read in the main loop (a clock call per
 * instruction would cost more than the instruction). */
static avr_cycle_count_t last_activity;
static int activity_seen; /* set here, cleared by the wall-clock check in the main loop */
static long bytes_received;
static void note_activity(void) {
  last_activity = avr->cycle;
  activity_seen = 1;
}

/* ---- UART output and the closing-line check ------------------------------------ */
static int opt_raw, opt_quiet;
static int pty_master = -1;
static long oks_seen;
static char line_buf[256];
static size_t line_len;
static long summary_passed = -1, summary_failed = -1;

static void check_line(void) {
  long p, f;
  line_buf[line_len] = 0;
  if (!strncmp(line_buf, "ok", 2)) oks_seen++;
  /* bktest's closing line: "N passed, N failed" (optionally ", N skipped") */
  if (sscanf(line_buf, "%ld passed, %ld failed", &p, &f) == 2) {
    summary_passed = p;
    summary_failed = f;
  }
  line_len = 0;
}

static void uart_out_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq;
  (void)param;
  char c = (char)value;
  note_activity();
  if (pty_master >= 0) {
    /* the host on the PTY sees the raw byte stream, CR included */
    if (write(pty_master, &c, 1) < 0) { /* host not reading: drop, as a real line would */ }
  }
  if (c == '\r' && !opt_raw) return;
  if (!opt_quiet) fputc(c, stdout);
  if (c == '\n') {
    fflush(stdout);
    check_line();
  } else if (line_len < sizeof line_buf - 1) {
    line_buf[line_len++] = c;
  }
}

/* ---- UART input, paced like a wire ------------------------------------------------
 * One byte per byte time at the baud rate the program configured, and only while
 * the receiver holds no unread byte (RXC0 clear). That suits polled readers and
 * interrupt-driven ones (Marlin) alike; simavr's XON/XOFF IRQs stall the latter
 * after 128 bytes. With --ok-pace a new line is only started after the program
 * answered the previous one with "ok", as Marlin hosts do. */
static FILE *in_file;
static int in_eof, opt_okpace;
static avr_irq_t *uart_in_irq;
static avr_cycle_count_t next_byte_cycle;
static long lines_sent;
/* Bytes read from the PTY and not yet delivered. One read() per byte time at
   most: a read() per simulated instruction (the first version) made a --pty
   run several times slower than a --input run. */
static unsigned char pty_buf[512];
static size_t pty_len, pty_pos;

static avr_cycle_count_t byte_cycles(void) {
  uint16_t ubrr = (uint16_t)(avr->data[ADDR_UBRR0L] | (avr->data[ADDR_UBRR0H] << 8));
  unsigned div = (avr->data[ADDR_UCSR0A] & (1 << U2X0_BIT)) ? 8 : 16;
  return (avr_cycle_count_t)10 * div * (ubrr + 1u); /* start + 8 data + stop bits */
}

static void feed_input(void) {
  if (!(avr->data[ADDR_UCSR0B] & (1 << RXEN0_BIT))) return; /* simavr drops such bytes */
  if (avr->data[ADDR_UCSR0A] & (1 << RXC0_BIT)) return;     /* unread byte waiting */
  if (avr->cycle < next_byte_cycle) return;
  int c = -1;
  if (pty_master >= 0) {
    if (pty_pos == pty_len) {
      ssize_t n = read(pty_master, pty_buf, sizeof pty_buf); /* non-blocking */
      if (n <= 0) {
        next_byte_cycle = avr->cycle + byte_cycles(); /* look again a byte time later */
        return;
      }
      pty_len = (size_t)n;
      pty_pos = 0;
    }
    c = pty_buf[pty_pos++];
  } else if (in_file && !in_eof) {
    if (opt_okpace && lines_sent > oks_seen) return;
    c = fgetc(in_file);
    if (c == EOF) {
      in_eof = 1;
      return;
    }
    if (c == '\n') lines_sent++;
  }
  if (c < 0) return;
  avr_raise_irq(uart_in_irq, (uint32_t)c);
  bytes_received++;
  note_activity();
  next_byte_cycle = avr->cycle + byte_cycles();
}

/* simavr's own messages ("Loaded N .text ...") would mix with the program's
   output on stdout, and its ADC warnings flood a Marlin run: errors only, on stderr. */
static void quiet_logger(struct avr_t *a, const int level, const char *fmt, va_list ap) {
  (void)a;
  if (level <= LOG_ERROR) vfprintf(stderr, fmt, ap);
}

/* ---- pin edges --------------------------------------------------------------------- */
static FILE *trace_file;
static uint8_t pin_level[12]; /* last level per port A..L, one bit per pin */
static void pin_hook(struct avr_irq_t *irq, uint32_t value, void *param) {
  (void)irq;
  uintptr_t id = (uintptr_t)param;
  /* simavr also reports a pin when its direction is set; keep real edges only */
  uint8_t *lv = &pin_level[(id >> 8) - 'A'], bit = (uint8_t)(1u << (id & 7));
  if (!!(*lv & bit) == (value & 1)) return;
  *lv ^= bit;
  note_activity();
  fprintf(trace_file, "%llu %c%u %u\n", (unsigned long long)avr->cycle, (char)(id >> 8),
          (unsigned)(id & 0xFF), (unsigned)(value & 1));
}

/* ---- benchmark markers ------------------------------------------------------------- */
static int opt_markers;
static avr_cycle_count_t mark_begin;
static uint32_t mark_last;
static uint8_t mark_read_index;
static unsigned long mark_count;

static void gpior0_write(struct avr_t *a, avr_io_addr_t addr, uint8_t v, void *param) {
  (void)param;
  a->data[addr] = v;
  if (v == 1) {
    mark_begin = a->cycle;
  } else if (v == 2) {
    /* a->cycle already includes the 1-cycle OUT that wrote the begin marker and
       this one; an empty BEGIN/END pair therefore measures 1 cycle. */
    avr_cycle_count_t d = a->cycle - mark_begin;
    mark_last = d > 0xFFFFFFFFull ? 0xFFFFFFFFu : (uint32_t)d;
    mark_read_index = 0;
    mark_count++;
    if (opt_markers) fprintf(stderr, "bksim: marker %lu: %u cycles\n", mark_count, mark_last);
  }
}
static uint8_t gpior1_read(struct avr_t *a, avr_io_addr_t addr, void *param) {
  (void)a; (void)addr; (void)param;
  uint8_t b = (uint8_t)(mark_last >> (8 * (mark_read_index & 3)));
  mark_read_index++;
  return b;
}

/* simavr would usleep() in real time while the AVR sleeps; we only want cycles. */
static void no_sleep(avr_t *a, avr_cycle_count_t how_long) { (void)a; (void)how_long; }

/* SIGINT/SIGTERM end the main loop, which then writes out what is buffered
   (a killed run used to lose the last few KB of its trace). */
static volatile sig_atomic_t stop_signal;
static void on_stop_signal(int sig) { stop_signal = sig; }

static double wall_seconds(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + (double)t.tv_nsec * 1e-9;
}

static void usage(void) {
  fprintf(stderr,
          "usage: bksim [options] program.elf\n"
          "  -m MCU            (default atmega2560)\n"
          "  -f HZ             clock (default 16000000)\n"
          "  --cycles N        cycle cap (default 800000000, ~50 s simulated); exceeding it fails\n"
          "  --input FILE|-    feed UART0 input from FILE or stdin, one byte per byte time\n"
          "  --ok-pace         with --input: start each line only after an \"ok\" (Marlin hosts)\n"
          "  --pty LINK        bridge UART0 to a new pseudo-terminal and symlink LINK to it\n"
          "  --trace FILE      write pin edges: '<cycle> <port><pin> <level>'\n"
          "  --trace-pins LIST pins to trace, e.g. F0,F1,F6,F7,L3,L1,A4,A6 (default: none)\n"
          "  --settle N        end the run N cycles after the input is used up (and, with\n"
          "                    --ok-pace, answered): for firmware that never stops\n"
          "  --idle-timeout S  end the run (exit 0) once the program has received a byte and\n"
          "                    then S seconds pass, simulated and wall-clock alike, with no\n"
          "                    UART byte either way and no edge on a traced pin (--pty runs)\n"
          "  --markers         print benchmark marker cycle counts on stderr\n"
          "  --no-test         do not require a bktest closing line\n"
          "  --raw             keep CR characters in the output\n"
          "  --quiet           do not copy UART output to stdout\n");
  exit(72);
}

int main(int argc, char **argv) {
  const char *mcu = "atmega2560", *elf = NULL, *input = NULL, *trace = NULL, *pins = NULL;
  const char *pty_link = NULL;
  unsigned long freq = 16000000UL;
  unsigned long long cap = 800000000ULL;
  unsigned long long settle = 0, settle_end = 0;
  double idle_timeout = 0;
  int opt_test = 1;
  for (int i = 1; i < argc; i++) {
    const char *a = argv[i];
    const char *next = i + 1 < argc ? argv[i + 1] : NULL;
    if (!strcmp(a, "-m") && next) mcu = argv[++i];
    else if (!strcmp(a, "-f") && next) freq = strtoul(argv[++i], NULL, 10);
    else if (!strcmp(a, "--cycles") && next) cap = strtoull(argv[++i], NULL, 10);
    else if (!strcmp(a, "--input") && next) input = argv[++i];
    else if (!strcmp(a, "--pty") && next) pty_link = argv[++i];
    else if (!strcmp(a, "--trace") && next) trace = argv[++i];
    else if (!strcmp(a, "--trace-pins") && next) pins = argv[++i];
    else if (!strcmp(a, "--markers")) opt_markers = 1;
    else if (!strcmp(a, "--ok-pace")) opt_okpace = 1;
    else if (!strcmp(a, "--settle") && next) settle = strtoull(argv[++i], NULL, 10);
    else if (!strcmp(a, "--idle-timeout") && next) {
      char *end;
      idle_timeout = strtod(argv[++i], &end);
      if (*end || !(idle_timeout > 0)) {
        fprintf(stderr, "bksim: --idle-timeout wants seconds > 0, got '%s'\n", argv[i]);
        return 72;
      }
    }
    else if (!strcmp(a, "--no-test")) opt_test = 0;
    else if (!strcmp(a, "--raw")) opt_raw = 1;
    else if (!strcmp(a, "--quiet")) opt_quiet = 1;
    else if (a[0] == '-' ) usage();
    else if (!elf) elf = a;
    else usage();
  }
  if (!elf) usage();

  avr_global_logger_set(quiet_logger);
  elf_firmware_t fw;
  memset(&fw, 0, sizeof fw);
  if (elf_read_firmware(elf, &fw) != 0) {
    fprintf(stderr, "bksim: cannot read ELF '%s'\n", elf);
    return 72;
  }
  if (!fw.mmcu[0]) strncpy(fw.mmcu, mcu, sizeof fw.mmcu - 1);
  if (!fw.frequency) fw.frequency = (uint32_t)freq;
  avr = avr_make_mcu_by_name(fw.mmcu);
  if (!avr) {
    fprintf(stderr, "bksim: unknown MCU '%s'\n", fw.mmcu);
    return 72;
  }
  avr_init(avr);
  avr->log = 1; /* errors only */
  avr_load_firmware(avr, &fw);
  avr->sleep = no_sleep;

  /* UART0: no console echo, no real-time sleeping in poll loops. */
  uint32_t flags = 0;
  avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
  flags &= ~(uint32_t)(AVR_UART_FLAG_STDIO | AVR_UART_FLAG_POLL_SLEEP);
  avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
  avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT),
                          uart_out_hook, NULL);
  uart_in_irq = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
  if (pty_link) {
    int slave;
    char name[128];
    if (openpty(&pty_master, &slave, name, NULL, NULL) != 0) {
      fprintf(stderr, "bksim: openpty failed: %s\n", strerror(errno));
      return 72;
    }
    /* raw mode on the slave side, so bytes pass unchanged */
    struct termios t;
    tcgetattr(slave, &t);
    cfmakeraw(&t);
    tcsetattr(slave, TCSANOW, &t);
    fcntl(pty_master, F_SETFL, fcntl(pty_master, F_GETFL) | O_NONBLOCK);
    unlink(pty_link);
    if (symlink(name, pty_link) != 0) {
      fprintf(stderr, "bksim: cannot link %s -> %s: %s\n", pty_link, name, strerror(errno));
      return 72;
    }
    fprintf(stderr, "bksim: UART0 on %s (%s)\n", pty_link, name);
  }
  if (input) {
    in_file = strcmp(input, "-") ? fopen(input, "rb") : stdin;
    if (!in_file) {
      fprintf(stderr, "bksim: cannot open input '%s': %s\n", input, strerror(errno));
      return 72;
    }
  }
  avr_register_io_write(avr, ADDR_GPIOR0, gpior0_write, NULL);
  avr_register_io_read(avr, ADDR_GPIOR1, gpior1_read, NULL);

  if (trace) {
    trace_file = fopen(trace, "w");
    if (!trace_file) {
      fprintf(stderr, "bksim: cannot write trace '%s': %s\n", trace, strerror(errno));
      return 72;
    }
    const char *p = pins ? pins : "";
    while (*p) {
      char port = p[0];
      int pin = p[1] - '0';
      if (port < 'A' || port > 'L' || pin < 0 || pin > 7) {
        fprintf(stderr, "bksim: bad pin '%s' in --trace-pins (want e.g. F0,L3)\n", p);
        return 72;
      }
      avr_irq_t *irq = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(port), pin);
      if (!irq) {
        fprintf(stderr, "bksim: no port %c on %s\n", port, fw.mmcu);
        return 72;
      }
      avr_irq_register_notify(irq, pin_hook, (void *)(uintptr_t)((port << 8) | pin));
      p += 2;
      if (*p == ',') p++;
    }
  }

  struct sigaction sa;
  memset(&sa, 0, sizeof sa);
  sa.sa_handler = on_stop_signal;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGINT, &sa, NULL);
  sigaction(SIGTERM, &sa, NULL);

  int state = cpu_Running;
  int capped = 0, tx_primed = 0, idled = 0;
  /* --idle-timeout bookkeeping: the wall clock is read every 2^16 cycles (4 ms
     simulated at 16 MHz); activity seen since the last read restarts it. */
  const avr_cycle_count_t idle_cycles = (avr_cycle_count_t)(idle_timeout * fw.frequency);
  avr_cycle_count_t next_clock_check = 0;
  double wall_activity = wall_seconds();
  while (!stop_signal) {
    /* simavr 1.6 quirk: UDRE0 is not set when the transmitter is enabled, and a
       polled writer then spins forever. Set it on every rising edge of TXEN0
       (simavr's reset state already has TXEN0 set, and Marlin clears the UART
       registers before enabling the transmitter again). */
    int txen = (avr->data[ADDR_UCSR0B] & (1 << TXEN0_BIT)) != 0;
    if (txen && !tx_primed) avr->data[ADDR_UCSR0A] |= (1 << UDRE0_BIT);
    tx_primed = txen;
    state = avr_run(avr);
    if (state == cpu_Done || state == cpu_Crashed) break;
    if (avr->cycle >= cap) {
      capped = 1;
      break;
    }
    if (pty_master >= 0 || (in_file && !in_eof)) feed_input();
    /* --settle: a firmware that never stops (Marlin) ends the run N cycles
       after its input is used up and, with --ok-pace, every line answered. */
    if (settle && in_eof && (!opt_okpace || oks_seen >= lines_sent)) {
      if (!settle_end) settle_end = avr->cycle + settle;
      if (avr->cycle >= settle_end) {
        state = cpu_Done;
        break;
      }
    }
    if (idle_cycles && avr->cycle >= next_clock_check) {
      next_clock_check = avr->cycle + 65536;
      double now = wall_seconds();
      if (activity_seen) {
        activity_seen = 0;
        wall_activity = now;
      } else if (bytes_received && avr->cycle - last_activity >= idle_cycles &&
                 now - wall_activity >= idle_timeout) {
        idled = 1;
        state = cpu_Done;
        break;
      }
    }
  }
  fflush(stdout);
  if (line_len) check_line();
  if (trace_file) fclose(trace_file);
  if (pty_link) unlink(pty_link);
  fprintf(stderr, "bksim: %llu cycles (%.3f s simulated)\n", (unsigned long long)avr->cycle,
          (double)avr->cycle / (double)fw.frequency);
  if (stop_signal) {
    fprintf(stderr, "bksim: stopped by signal %d; output and trace written\n", (int)stop_signal);
    return 128 + stop_signal;
  }
  if (idled)
    fprintf(stderr, "bksim: idle for %g s (no UART byte, no traced edge): run ended\n", idle_timeout);
  if (capped) {
    fprintf(stderr, "bksim: FAIL: cycle cap of %llu reached (hung program?)\n", cap);
    return 70;
  }
  if (state == cpu_Crashed) {
    fprintf(stderr, "bksim: FAIL: program crashed\n");
    return 71;
  }
  if (opt_test) {
    if (summary_failed < 0) {
      fprintf(stderr, "bksim: FAIL: no closing 'N passed, N failed' line\n");
      return 66;
    }
    return summary_failed ? 65 : 0;
  }
  return 0;
}
