// sinewall: prints the figures of the sine-wave wall test (Jang & Hong 2017,
// Fig. 4) run through the width mode core: widths, head speeds, extruder-rate
// spread, clamping; then what a planner with constant acceleration does to the
// extruder rate at the speed changes (the core cannot see that part).
//
//   make -C tools/sinewall run        (or: tools/sinewall/sinewall [options])
//   options: -L <mm/s> -U <mm/s> -A <amp mm> -a <accel mm/s^2> -E (infill as E, not W)
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sinewall.h"

namespace {

const int kMaxMoves = 1024;

struct Collected {
  sinewall::Move m[kMaxMoves];
  int n;
};

void collect(const sinewall::Move &m, void *ctx) {
  Collected *c = static_cast<Collected *>(ctx);
  if (c->n < kMaxMoves) c->m[c->n++] = m;
}

void print_figures(const char *title, const sinewall::Spec &s, const sinewall::Figures &f) {
  printf("%s\n", title);
  printf("  wall       %.0f mm long, thickness %.2f..%.2f mm, wave %.0f mm, layer %.2f mm, %.2f mm walls\n",
         s.length, s.t_mid - s.t_amp, s.t_mid + s.t_amp, s.wavelength, s.h, s.wall_w);
  printf("  M723       Q%.3f mm3/s (r %.4f mm/s of %.2f mm filament)  L%.1f U%.1f  infill sent as %s\n",
         f.q, f.r, s.dia, s.min_v, s.max_v, s.use_w ? "W words" : "E at F40");
  printf("  moves      %u extruding (%u unclamped, %u clamped), %u travels/retractions untouched%s\n",
         f.moves, f.unclamped, f.clamped, f.untouched, f.untouched_bad ? " -- SOME CHANGED" : "");
  printf("  widths     %.3f .. %.3f mm (ratio %.1f)\n", f.w_min, f.w_max, f.w_max / f.w_min);
  printf("  speeds     %.2f .. %.2f mm/s\n", f.v_min, f.v_max);
  if (f.unclamped)
    printf("  E rate     %.6f .. %.6f mm/s on unclamped moves: spread %.2e of r (goal: < 1e-3)\n", f.r_min,
           f.r_max, f.spread);
  if (f.clamped)
    printf("  clamped    rate deviation max %.1f %%, mean %.1f %%\n", f.clamp_max_dev * 100, f.clamp_mean_dev * 100);
  printf("  without    same E at constant F%.0f: E rate %.4f .. %.4f mm/s (spread %.0f %% of r)\n", s.v0,
         f.plain_r_min, f.plain_r_max, (f.plain_r_max - f.plain_r_min) / f.r * 100);
  printf("  time       %.2f s extruding (filament %.2f mm / r = %.2f s); at constant F%.0f: %.2f s\n", f.time_s,
         f.filament, f.filament / f.r, s.v0, f.plain_time_s);
  if (f.errors) printf("  ERRORS     %u replies were Error:\n", f.errors);
}

// Time during which the head runs below 99 % of a block's own speed while it
// ramps with acceleration a from speed lo up to hi (or down): that is where the
// extruder rate, slaved to the head, is more than 1 % under r.
double slow_time(double lo, double hi, double v, double a) {
  double top = 0.99 * v;
  if (hi > top) hi = top;
  return hi > lo ? (hi - lo) / a : 0.0;
}

// Junction speeds as a planner without cornering limits would choose them:
// min of the neighbours, then the usual backward and forward passes; the line
// starts and ends at rest (stop = true) or at its own first/last speed.
void accel_figures(const Collected &c, uint8_t line, double a, bool stop, double &total, double &slow,
                   double &worst) {
  static double j[kMaxMoves + 1];
  int idx[kMaxMoves];
  int n = 0;
  for (int i = 0; i < c.n; i++)
    if (c.m[i].line == line) idx[n++] = i;
  total = slow = 0;
  worst = 0;
  if (!n) return;
  j[0] = stop ? 0 : c.m[idx[0]].v;
  j[n] = stop ? 0 : c.m[idx[n - 1]].v;
  for (int k = 1; k < n; k++) j[k] = fmin(c.m[idx[k - 1]].v, c.m[idx[k]].v);
  for (int k = n - 1; k >= 0; k--) j[k] = fmin(j[k], sqrt(j[k + 1] * j[k + 1] + 2 * a * c.m[idx[k]].len));
  for (int k = 1; k <= n; k++) j[k] = fmin(j[k], sqrt(j[k - 1] * j[k - 1] + 2 * a * c.m[idx[k - 1]].len));
  for (int k = 0; k < n; k++) {
    const sinewall::Move &m = c.m[idx[k]];
    double v = m.v, e = j[k], x = j[k + 1], len = m.len;
    // Peak speed: reached if accel + decel distances fit, else where they meet.
    double peak = sqrt((2 * a * len + e * e + x * x) / 2);
    if (peak > v) peak = v;
    double d_acc = (peak * peak - e * e) / (2 * a), d_dec = (peak * peak - x * x) / (2 * a);
    double t = (peak - e) / a + (peak - x) / a + (len - d_acc - d_dec) / peak;
    total += t;
    slow += slow_time(e, peak, v, a) + slow_time(x, peak, v, a);
    double low = fmin(e, x);
    if (1 - low / v > worst) worst = 1 - low / v;
  }
}

}  // namespace

int main(int argc, char **argv) {
  sinewall::Spec s = sinewall::default_spec();
  double accel[3] = {500, 1000, 3000};
  int n_accel = 3;
  for (int i = 1; i < argc; i++) {
    const char *o = argv[i];
    if (!strcmp(o, "-E")) {
      s.use_w = false;
      continue;
    }
    if (i + 1 >= argc || o[0] != '-' || strlen(o) != 2) {
      fprintf(stderr, "usage: sinewall [-L mm/s] [-U mm/s] [-A amplitude mm] [-a accel mm/s^2] [-E]\n");
      return 2;
    }
    float v = (float)atof(argv[++i]);
    switch (o[1]) {
      case 'L': s.min_v = v; break;
      case 'U': s.max_v = v; break;
      case 'A': s.t_amp = v; break;
      case 'a': accel[0] = v; n_accel = 1; break;
      default:
        fprintf(stderr, "sinewall: unknown option %s\n", o);
        return 2;
    }
  }
  static bk::WidthMode mode;
  static Collected c;
  sinewall::Figures f;
  c.n = 0;
  sinewall::run(s, mode, f, collect, &c);
  if (f.errors) {
    fprintf(stderr, "sinewall: the core refused the settings (check -L/-U/-A)\n");
    return 1;
  }
  print_figures("Sine-wave wall through width mode (core output, no acceleration)", s, f);
  if (f.moves != c.n) {
    fprintf(stderr, "sinewall: more moves than the tool keeps\n");
    return 1;
  }
  printf("\nPlanner acceleration (infill line; the extruder follows the head through every ramp)\n");
  printf("  accel       time s   E rate >1 %% under r (time share)   worst dip   [stop at ends | interior only]\n");
  for (int k = 0; k < n_accel; k++) {
    double t1, s1, w1, t2, s2, w2;
    accel_figures(c, 2, accel[k], true, t1, s1, w1);
    accel_figures(c, 2, accel[k], false, t2, s2, w2);
    printf("  %5.0f mm/s2  %6.2f   %5.2f s (%4.1f %%) | %5.3f s (%4.1f %%)      %4.1f %% | %4.1f %%\n", accel[k], t1,
           s1, 100 * s1 / t1, s2, 100 * s2 / t2, 100 * w1, 100 * w2);
  }
  return (f.untouched_bad || f.spread > 1e-3f) ? 1 : 0;
}
