// Flash/RAM probe for the portable core on an ATmega2560 (or a Cortex-M): calls every entry point
// the Marlin adapter calls, with inputs the compiler cannot see, so LTO keeps
// exactly what the firmware would keep. `make size` builds it and lists symbols.
// Not a test and never run; the Marlin build gives the real figure
// (docs/verification/marlin-simulation.md), this one is for quick iteration.
#ifdef __AVR__
#include <avr/io.h>
#else
// Cortex-M (ARCH=cm3|cm4f in size.sh): a UART data register of some board
#define UDR0 (*(volatile uint8_t *)0x40004000u)
#endif
// As in the firmware: replies go to the serial port (the Marlin adapter defines
// ReplyText there on Marlin's own printing, which the stock build already has;
// here each piece is one opaque UART write, so only the core's calls count;
// fixed() is the core's own, in reply_text.cpp).
// (size.sh builds every file with -DBK_REPLY_SERIAL=1)
#include "bulge_map.h"
#include "bulge_planner.h"
#include "gcode_args.h"
#include "map_upload.h"
#include "width_mode.h"

// Which features the probe keeps (size.sh sets them; both by default), as the
// Marlin options BULGE_MAP and WIDTH_BY_FEEDRATE do.
#ifndef BK_PROBE_BULGE
#define BK_PROBE_BULGE 1
#endif
#ifndef BK_PROBE_WIDTH
#define BK_PROBE_WIDTH 1
#endif
#if BK_PROBE_BULGE
static bk::MapStore store;
static bk::MapUpload upload(store);
static bk::BulgePlanner bulge;
static bk::ActionList actions;
#endif
#if BK_PROBE_WIDTH
static bk::WidthMode width;
#endif

static char line[96];

namespace bk {
ReplyText::ReplyText(char *, uint16_t) : b_(nullptr), size_(0), n_(0), cut_(false) {}
__attribute__((noinline)) void ReplyText::c(char ch) { n_++; UDR0 = ch; }
__attribute__((noinline)) void ReplyText::p(const char *f) { n_++; UDR0 = (uint8_t)(uintptr_t)f; }
__attribute__((noinline)) void ReplyText::raw(const char *s, uint8_t n) { while (n--) c(*s++); }
__attribute__((noinline)) void ReplyText::u(uint32_t v) { n_++; UDR0 = (uint8_t)v; }
}  // namespace bk

static void read_line() {
  for (uint8_t i = 0; i < sizeof(line); ++i) line[i] = (char)UDR0;  // opaque input
}
static float in_f() {
  union { uint32_t u; float f; } v;
  v.u = (uint32_t)UDR0 << 24 | (uint32_t)UDR0 << 16 | (uint32_t)UDR0 << 8 | UDR0;
  return v.f;
}

int main() {
#if BK_PROBE_BULGE
  bulge.attach(&store);
#endif
  for (;;) {
    read_line();
    bk::GcodeArgs a;
    if (!a.parse(line)) continue;
    bk::ReplyText reply(nullptr, 0);
    switch (a.code()) {
#if BK_PROBE_BULGE
      case 720: bulge.m720(a, reply); break;
      case 721: upload.handle(a, reply); if (UDR0) bulge.map_changed(); break;
      case 722: bulge.m722(a, reply); break;
      case 503: bulge.report(reply, UDR0); break;  // M503 (Marlin's default configuration has it)
#endif
#if BK_PROBE_WIDTH
      case 723: width.command(a, reply); break;
      case 504: width.report(reply, UDR0, false); break;
#endif
      default: {
        bk::Move m;
        m.x0 = in_f(); m.y0 = in_f(); m.z0 = in_f();
        m.x1 = in_f(); m.y1 = in_f(); m.z1 = in_f();
        m.e = in_f(); m.f = in_f();
#if BK_PROBE_WIDTH
        width.set_feed_percent((int16_t)UDR0);
        float de = m.e;
        if (UDR0) width.width_e_xy(in_f(), UDR0, m.x1 - m.x0, m.y1 - m.y0, de, reply);
        m.f = width.feed_xy(m.x1 - m.x0, m.y1 - m.y0, de, m.f);
#endif
#if BK_PROBE_BULGE
        bool more = bulge.plan(m, actions);
        for (;;) {
          for (uint8_t i = 0; i < actions.count; ++i) UDR0 = (uint8_t)actions.a[i].x;
          if (!more) break;
          more = bulge.plan_more(actions);
        }
#else
        UDR0 = (uint8_t)m.f;
#endif
      }
    }
    if (!reply.empty()) UDR0 = '\n';
  }
}
