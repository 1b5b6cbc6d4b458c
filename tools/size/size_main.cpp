// Flash/RAM probe for the portable core on an ATmega2560: calls every entry point
// the Marlin adapter calls, with inputs the compiler cannot see, so LTO keeps
// exactly what the firmware would keep. `make size` builds it and lists symbols.
// Not a test and never run; the Marlin build gives the real figure
// (docs/marlin-integration.md), this one is for quick iteration.
#include <avr/io.h>
#include "bulge_map.h"
#include "bulge_planner.h"
#include "gcode_args.h"
#include "map_upload.h"
#include "width_mode.h"

static bk::MapStore store;
static bk::MapUpload upload(store);
static bk::BulgePlanner bulge;
static bk::WidthMode width;
static bk::ActionList actions;

static char line[96];
static char reply[200];

static void read_line() {
  for (uint8_t i = 0; i < sizeof(line); ++i) line[i] = (char)UDR0;  // opaque input
}
static void write_reply() {
  for (const char *p = reply; *p; ++p) UDR0 = *p;
}
static float in_f() {
  union { uint32_t u; float f; } v;
  v.u = (uint32_t)UDR0 << 24 | (uint32_t)UDR0 << 16 | (uint32_t)UDR0 << 8 | UDR0;
  return v.f;
}

int main() {
  bulge.attach(&store);
  for (;;) {
    read_line();
    bk::GcodeArgs a;
    if (!a.parse(line)) continue;
    switch (a.code()) {
      case 720: bulge.m720(a, reply, sizeof(reply)); break;
      case 721: upload.handle(a, reply, sizeof(reply)); if (UDR0) bulge.map_changed(); break;
      case 722: bulge.m722(a, reply, sizeof(reply)); break;
      case 723: width.command(a, reply, sizeof(reply)); break;
      default: {
        bk::Move m;
        m.x0 = in_f(); m.y0 = in_f(); m.z0 = in_f();
        m.x1 = in_f(); m.y1 = in_f(); m.z1 = in_f();
        m.e = in_f(); m.f = in_f();
        width.set_feed_percent((int16_t)UDR0);
        float de = m.e;
        if (UDR0) width.width_e_xy(in_f(), UDR0, m.x1 - m.x0, m.y1 - m.y0, de, reply, sizeof(reply));
        m.f = width.feed_xy(m.x1 - m.x0, m.y1 - m.y0, de, m.f);
        bool more = bulge.plan(m, actions);
        for (;;) {
          for (uint8_t i = 0; i < actions.count; ++i) UDR0 = (uint8_t)actions.a[i].x;
          if (!more) break;
          more = bulge.plan_more(actions);
        }
      }
    }
    write_reply();
  }
}
