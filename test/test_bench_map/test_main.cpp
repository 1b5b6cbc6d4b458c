// Map codec costs: cycles on the simulated ATmega2560 (ns on the host),
// printed as a table, plus the realistic case's bytes per point.
//
// The number that matters while printing is find_layer at a layer change: it
// walks the record heads up to the wanted z and decodes one record (up to 64
// points) with the same checked decoder that validates an upload. Loading, CRCs and M721 commit run once per upload, not per move.
// Each case asserts that it did its work (counts, results) and, on AVR, that
// the cycles stay within a budget that keeps a layer change well under 1 ms
// of stall at 16 MHz (the dwell at a bulge point is ~100 ms for comparison).
#include <string.h>

#include "bktest.h"
#include "bulge_map.h"
#include "gcode_args.h"
#include "map_upload.h"
#include "../vectors/vectors.h"

#ifdef __AVR__
#define FLASH_COPY(dst, src, n) memcpy_P((dst), (src), (n))
#else
#define FLASH_COPY(dst, src, n) memcpy((dst), (src), (n))
#endif

using namespace bk;

static MapStore store;
static MapLayer layer;
static uint8_t scratch[sizeof bkv_text_cylinder];
static char line[100];
static char reply[BK_M721_REPLY_BYTES];

void setUp(void) { store.clear(); }

static void row(const char *label_flash, uint32_t value, uint32_t per, const char *per_flash) {
  bkt_puts("| ");
  bkt_puts_P(label_flash);
  bkt_puts(" | ");
  bkt_put_uint(value);
  bkt_putc(' ');
  bkt_puts(bkt_bench_unit());
  bkt_puts(" | ");
  bkt_put_uint(per);
  bkt_putc(' ');
  bkt_puts_P(per_flash);
  bkt_puts(" |\n");
}
#define ROW(label, v, per, unit) row(BKT_S(label), v, per, BKT_S(unit))

// AVR budget check; on the host only that the clock moved sensibly (< 20 ms).
static void budget(uint32_t v, uint32_t avr_cycles) {
  if (bkt_on_avr()) TEST_ASSERT_LESS_OR_EQUAL_INT((int32_t)avr_cycles, (int32_t)v);
  else TEST_ASSERT_LESS_THAN_INT(20000000L, (int32_t)v);
}

static void load_vector(const uint8_t *flash, uint16_t n) {
  FLASH_COPY(scratch, flash, n);
  TEST_ASSERT_EQUAL_INT(MAP_OK, store.load(scratch, n));
}

static void test_table_header(void) {
  TEST_MESSAGE("| case | time | per unit |");
  TEST_MESSAGE("|---|---|---|");
#if defined(__AVR__) && !defined(__OPTIMIZE__)
  // The firmware is built with -Os; unoptimized cycle counts are 2-3x higher
  // and would make every budget below meaningless.
  TEST_FAIL_MESSAGE("AVR bench built without optimization (-Os missing from the build flags)");
#endif
}

static void test_decode_64_point_layer(void) {
  load_vector(bkv_full_layer, sizeof bkv_full_layer);
  BKT_BENCH_BEGIN();
  bool found = store.find_layer(300, layer);
  BKT_BENCH_END();
  uint32_t t = bkt_bench_last();
  TEST_ASSERT_TRUE(found);
  TEST_ASSERT_EQUAL_UINT8(64, layer.count);
  TEST_ASSERT_EQUAL_UINT8((37 * 63) % 256, layer.pts[63].w);
  ROW("find_layer: decode one 64-point record (weights)", t, t / 64, "/point");
  budget(t, 16000);  // 1 ms
}

static void test_find_layer_in_realistic_map(void) {
  load_vector(bkv_text_cylinder, sizeof bkv_text_cylinder);
  const uint16_t first = store.first_z(), last = store.last_z();
  BKT_BENCH_BEGIN();
  bool f1 = store.find_layer(first, layer);
  BKT_BENCH_END();
  uint32_t t1 = bkt_bench_last();
  TEST_ASSERT_TRUE(f1);
  TEST_ASSERT_EQUAL_UINT16(first, layer.z_cmm);
  const uint8_t n1 = layer.count;
  BKT_BENCH_BEGIN();
  bool f2 = store.find_layer(last, layer);
  BKT_BENCH_END();
  uint32_t t2 = bkt_bench_last();
  TEST_ASSERT_TRUE(f2);
  TEST_ASSERT_EQUAL_UINT16(last, layer.z_cmm);
  BKT_BENCH_BEGIN();
  bool f3 = store.find_layer(last + 100, layer);
  BKT_BENCH_END();
  uint32_t t3 = bkt_bench_last();
  TEST_ASSERT_FALSE(f3);
  ROW("find_layer: text_cylinder first layer", t1, t1 / n1, "/point");
  ROW("find_layer: text_cylinder last layer (walks 33 records)", t2, t2 / layer.count, "/point");
  ROW("find_layer: above the map (walks all 34, no decode)", t3, t3 / 34, "/record");
  budget(t2, 16000);
  budget(t3, 8000);
}

static void test_crc_2k(void) {
  // The arena's 2 KiB as data: any bytes do.
  load_vector(bkv_text_cylinder, sizeof bkv_text_cylinder);
  const uint8_t *p = store.records();
  BKT_BENCH_BEGIN();
  uint8_t c8 = crc8(p, BK_MAP_ARENA_BYTES);
  BKT_BENCH_END();
  uint32_t t8 = bkt_bench_last();
  BKT_BENCH_BEGIN();
  uint32_t c32 = crc32_update(0, p, BK_MAP_ARENA_BYTES);
  BKT_BENCH_END();
  uint32_t t32 = bkt_bench_last();
  // Results checked against a split computation, so the work was really done.
  TEST_ASSERT_EQUAL_HEX8(crc8(p + 1000, BK_MAP_ARENA_BYTES - 1000, crc8(p, 1000)), c8);
  TEST_ASSERT_EQUAL_HEX32(crc32_update(crc32_update(0, p, 7), p + 7, BK_MAP_ARENA_BYTES - 7), c32);
  ROW("crc8 over 2048 bytes", t8, t8 / BK_MAP_ARENA_BYTES, "/byte");
  ROW("crc32 over 2048 bytes", t32, t32 / BK_MAP_ARENA_BYTES, "/byte");
  // Bit at a time (no tables, 120 bytes of code for both): ~77 and ~123 cycles a byte
  budget(t8, 2048UL * 80);
  budget(t32, 2048UL * 140);
}

static void test_load_and_release(void) {
  const uint16_t n = sizeof bkv_text_cylinder;
  FLASH_COPY(scratch, bkv_text_cylinder, n);
  BKT_BENCH_BEGIN();
  MapError e = store.load(scratch, n);
  BKT_BENCH_END();
  uint32_t tl = bkt_bench_last();
  TEST_ASSERT_EQUAL_INT(MAP_OK, e);
  TEST_ASSERT_EQUAL_UINT16(484, store.point_count());
  const uint16_t used = store.bytes_used();
  BKT_BENCH_BEGIN();
  store.release_below(store.first_z() + 1);
  BKT_BENCH_END();
  uint32_t tr = bkt_bench_last();
  TEST_ASSERT_EQUAL_UINT16(33, store.layer_count());
  ROW("load: validate + copy text_cylinder (1562 bytes)", tl, tl / n, "/byte");
  ROW("release_below: drop 1 layer, move the rest", tr, tr / (store.bytes_used() ? store.bytes_used() : 1),
      "/byte moved");
  TEST_ASSERT_TRUE(store.bytes_used() < used);
  budget(tl, 1562UL * 200);  // one-time: a full 2 KiB arena validates in ~25 ms
  budget(tr, 16000);
}

static UploadStatus send(MapUpload &up, GcodeArgs &a) {
  TEST_ASSERT_TRUE(a.parse(line));
  return up.handle(a, reply, sizeof reply);
}

static void test_m721_chunk_and_commit(void) {
  // The transcript's own lines: begin, chunks, commit of text_cylinder_head.
  MapUpload up(store);
  GcodeArgs a;
  const char *s = bkv_text_cylinder_m721;
  uint32_t chunk_max = 0, commit = 0;
  uint8_t commits = 0;
  for (;;) {
    uint8_t n = 0;
    char c;
#ifdef __AVR__
    while ((c = (char)pgm_read_byte(s)) && c != '\n') line[n++] = c, s++;
#else
    while ((c = *s) && c != '\n') line[n++] = c, s++;
#endif
    line[n] = 0;
    if (c) s++;
    if (!c && !n) break;
    if (line[0] == ';') continue;
    const bool is_commit = strstr(line, " E*") != 0;
    const bool is_chunk = strstr(line, " O") != 0;
    BKT_BENCH_BEGIN();
    UploadStatus st = send(up, a);
    BKT_BENCH_END();
    uint32_t t = bkt_bench_last();
    TEST_ASSERT_TRUE(st != UPLOAD_ERROR);
    if (is_chunk && t > chunk_max) chunk_max = t;
    if (is_commit && !commits++) commit = t;  // the first commit: a new map
  }
  TEST_ASSERT_EQUAL_INT(2, commits);
  TEST_ASSERT_EQUAL_UINT16(34, store.layer_count());
  ROW("M721 chunk line: parse + base32 40 bytes (max)", chunk_max, chunk_max / 40, "/byte");
  ROW("M721 E: CRC-32 + validate text_cylinder_head (785 bytes)", commit, commit / 785, "/byte");
  budget(chunk_max, 16000);
  budget(commit, 785UL * 360);  // one-time: CRC-32 + validation, ~16 ms here
}

static void test_bytes_per_point(void) {
  load_vector(bkv_text_cylinder, sizeof bkv_text_cylinder);
  const uint16_t n = sizeof bkv_text_cylinder, pts = store.point_count();
  TEST_ASSERT_EQUAL_UINT16(484, pts);
  // Hundredths of a byte per point, integer maths (no printf-float on AVR).
  const uint32_t bpp100 = ((uint32_t)n * 100 + pts / 2) / pts;
  bkt_puts("| text_cylinder: 484 points in 34 layers, ");
  bkt_put_uint(n);
  bkt_puts(" bytes (8 header) | ");
  bkt_put_uint(bpp100 / 100);
  bkt_putc('.');
  bkt_put_uint(bpp100 / 10 % 10);
  bkt_put_uint(bpp100 % 10);
  bkt_puts(" bytes/point |\n");
  TEST_ASSERT_EQUAL_UINT32(323, bpp100);
  TEST_ASSERT_LESS_OR_EQUAL_INT(350, (int32_t)bpp100);
  TEST_ASSERT_EQUAL_UINT16(n - 8, store.bytes_used());
  // RAM the codec costs: the store and one decoded layer.
  bkt_puts("| RAM: MapStore ");
  bkt_put_uint(sizeof(MapStore));
  bkt_puts(" bytes, MapLayer ");
  bkt_put_uint(sizeof(MapLayer));
  bkt_puts(" bytes, MapUpload ");
  bkt_put_uint(sizeof(MapUpload));
  bkt_puts(" bytes | |\n");
  TEST_ASSERT_LESS_OR_EQUAL_INT(BK_MAP_ARENA_BYTES + 32, (int32_t)sizeof(MapStore));
}

int main(void) {
  UNITY_BEGIN();
  RUN_TEST(test_table_header);
  RUN_TEST(test_decode_64_point_layer);
  RUN_TEST(test_find_layer_in_realistic_map);
  RUN_TEST(test_crc_2k);
  RUN_TEST(test_load_and_release);
  RUN_TEST(test_m721_chunk_and_commit);
  RUN_TEST(test_bytes_per_point);
  return UNITY_END();
}
