// bkcore: runs the portable firmware core on a G-code stream, natively.
//
//   bkcore [--map FILE.bkm] < input.gcode
//
// Reads G-code on stdin and prints, one per line, what the firmware would do:
//   line X<x> Y<y> Z<z> E<de> F<f>   a linear piece; E is the filament of this
//                                    piece (a delta, extra included), F mm/min
//   dwell <ms>                       a stop (bulge point, or the host's own G4)
//   echo:... / Error:...             replies of M720, M721, M722, M723
//   pass <line>                      a line the core does not handle
// and at the end one "summary ..." line. M720-M723, G0/G1 (with W words in
// width mode), G92, G90/G91, M82/M83 and G4 are handled, in the order the
// Marlin adapter applies them: width mode sets the move's filament (W) and
// speed, then the bulge planner splits it and every piece keeps that speed.
// --map loads a compact map file instead of (or before) M721 uploads in the
// input. Exit status 1 if any line gave an Error.
//
// Used by the host toolkit's end-to-end check and by the README demo.
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "bulge_map.h"
#include "bulge_planner.h"
#include "gcode_args.h"
#include "map_upload.h"
#include "move_state.h"
#include "width_mode.h"

namespace {

bk::MapStore store;
bk::MapUpload upload(store);
bk::BulgePlanner planner;
bk::MoveState state;
bk::WidthMode width;

struct Totals {
  unsigned long moves = 0, lines = 0, dwells = 0, dwell_ms = 0, errors = 0, passed = 0;
  double e_host = 0, e_out = 0;  // filament the G-code asked for / the core drove
} tot;

void print_reply(const char *r) {
  if (*r) printf("%s\n", r);
  if (!strncmp(r, "Error:", 6) || strstr(r, "\nError:")) tot.errors++;
}

void do_move(const bk::AxisWords &w, const bk::GcodeArgs &args) {
  const bk::MoveState before = state;
  bk::Move m = state.line(w);
  float wv;
  const bk::ArgStatus ws = args.get_float('W', wv);
  if (ws == bk::ARG_BAD || ws == bk::ARG_EMPTY) {
    print_reply("Error:G1 bad value for W");
    state = before;  // the move is not executed
    return;
  }
  if (ws == bk::ARG_OK) {
    // Width mode: the filament comes from the width; the host's E does not
    // count it, so it goes into the internal E offset as the bulge extra does.
    char err[bk::WidthMode::ERROR_REPLY_MIN];
    float de;
    if (!width.width_e_xy(wv, (w.mask & bk::AxisWords::E) != 0, m.x1 - m.x0, m.y1 - m.y0, de, err, sizeof err)) {
      print_reply(err);
      state = before;
      return;
    }
    m.e = de;
    state.add_e_offset(de);
  }
  if (!(w.mask & (bk::AxisWords::X | bk::AxisWords::Y | bk::AxisWords::Z | bk::AxisWords::E)) && ws == bk::ARG_ABSENT)
    return;  // "G1 F1800"
  m.f = width.feed_xy(m.x1 - m.x0, m.y1 - m.y0, m.e, m.f / 60.0f) * 60.0f;  // identity when the mode is off
  tot.moves++;
  tot.e_host += m.e;
  bk::ActionList out;
  bool more = planner.plan(m, out);
  for (;;) {
    for (uint8_t i = 0; i < out.count; i++) {
      const bk::Action &a = out.a[i];
      if (a.kind == bk::Action::LINE) {
        printf("line X%.3f Y%.3f Z%.3f E%.5f F%.0f\n", a.x, a.y, a.z, a.e, m.f);
        tot.lines++;
        tot.e_out += a.e;
      } else {
        printf("dwell %u\n", (unsigned)a.ms);
        tot.dwells++;
        tot.dwell_ms += a.ms;
      }
    }
    state.add_e_offset(out.e_added);
    if (!more) break;
    more = planner.plan_more(out);
  }
}

bool load_map(const char *path) {
  FILE *f = fopen(path, "rb");
  if (!f) {
    fprintf(stderr, "bkcore: %s: cannot open\n", path);
    return false;
  }
  static uint8_t buf[BK_MAP_ARENA_BYTES + bk::MAP_HEADER_BYTES + 1];
  size_t n = fread(buf, 1, sizeof buf, f);
  fclose(f);
  if (n > BK_MAP_ARENA_BYTES + bk::MAP_HEADER_BYTES) {
    fprintf(stderr, "bkcore: %s: larger than the %d-byte arena\n", path, BK_MAP_ARENA_BYTES);
    return false;
  }
  bk::MapError e = store.load(buf, (uint16_t)n);
  if (e != bk::MAP_OK) {
    char t[64];
    bk::map_error_copy(e, t, sizeof t);
    fprintf(stderr, "bkcore: %s: rejected: %s\n", path, t);
    return false;
  }
  planner.map_changed();
  return true;
}

}  // namespace

int main(int argc, char **argv) {
  planner.attach(&store);
  for (int i = 1; i < argc; i++) {
    if (!strcmp(argv[i], "--map") && i + 1 < argc) {
      if (!load_map(argv[++i])) return 2;
    } else {
      fprintf(stderr, "usage: bkcore [--map FILE.bkm] < input.gcode\n");
      return 2;
    }
  }
  char line[256];
  unsigned long lineno = 0;
  while (fgets(line, sizeof line, stdin)) {
    lineno++;
    size_t len = strlen(line);
    if (len == sizeof line - 1 && line[len - 1] != '\n') {
      printf("Error:line %lu longer than %u characters\n", lineno, (unsigned)sizeof line - 2);
      tot.errors++;
      int c;
      while ((c = getchar()) != EOF && c != '\n') {
      }
      continue;
    }
    while (len && (line[len - 1] == '\n' || line[len - 1] == '\r')) line[--len] = 0;
    const char *p = line;
    while (*p == ' ' || *p == '\t') p++;
    if (!*p) continue;
    bk::GcodeArgs a;
    if (!a.parse(p)) {  // comments and anything that is not an M/G code
      printf("pass %s\n", p);
      tot.passed++;
      continue;
    }
    char reply[BK_M721_REPLY_BYTES];
    reply[0] = 0;
    const char L = a.code_letter();
    const int code = a.code();
    if (L == 'M' && code == 720) {
      planner.m720(a, reply, sizeof reply);
      print_reply(reply);
    } else if (L == 'M' && code == 723) {
      char wreply[bk::WidthMode::REPLY_MIN];
      width.command(a, wreply, sizeof wreply);
      print_reply(wreply);
    } else if (L == 'M' && code == 722) {
      planner.m722(a, reply, sizeof reply);
      print_reply(reply);
    } else if (L == 'M' && code == 721) {
      bk::UploadStatus s = upload.handle(a, reply, sizeof reply);
      // A replaced or cleared map invalidates the decoded layer; appended
      // records do not touch it.
      if ((s == bk::UPLOAD_COMMITTED && !upload.appending()) || s == bk::UPLOAD_CLEARED) planner.map_changed();
      print_reply(reply);
    } else if (L == 'M' && (code == 82 || code == 83)) {
      state.set_e_absolute(code == 82);
    } else if (L == 'G' && (code == 90 || code == 91)) {
      state.set_absolute(code == 90);
    } else if (L == 'G' && (code == 0 || code == 1 || code == 92)) {
      bk::AxisWords w;
      char bad = bk::MoveState::words_from(a, w);
      if (bad) {
        printf("Error:G%d bad value for %c (line %lu)\n", code, bad, lineno);
        tot.errors++;
      } else if (code == 92) {
        state.set_position(w);
      } else {
        do_move(w, a);
      }
    } else if (L == 'G' && code == 4) {
      int32_t ms = 0;
      float sec = 0;
      if (a.get_long('P', ms) == bk::ARG_OK && ms >= 0) {
      } else if (a.get_float('S', sec) == bk::ARG_OK && sec >= 0) {
        ms = (int32_t)(sec * 1000.0f + 0.5f);
      }
      printf("dwell %ld\n", (long)ms);
      tot.dwells++;
      tot.dwell_ms += (unsigned long)ms;
    } else {
      printf("pass %s\n", p);
      tot.passed++;
    }
  }
  const bk::PlannerStats &st = planner.stats();
  printf("summary moves:%lu lines:%lu dwells:%lu dwell_ms:%lu points:%lu split_moves:%lu extra:%.5f dropped:%.5f "
         "e_gcode:%.5f e_out:%.5f host_e:%.5f e_offset:%.5f pos:X%.3f Y%.3f Z%.3f errors:%lu passed:%lu\n",
         tot.moves, tot.lines, tot.dwells, tot.dwell_ms, (unsigned long)st.points_fired, (unsigned long)st.moves_split,
         st.extra_applied, st.extra_dropped, tot.e_host, tot.e_out, state.e(), state.e_offset(), state.x(), state.y(),
         state.z(), tot.errors, tot.passed);
  return tot.errors ? 1 : 0;
}
