// libFuzzer target: the compact map decoder (MapStore::load / load_parts /
// append / find_layer / neighbors / release_below, map_decode_record).
//
// Input: byte 0 picks the mode, the rest is the data.
//   even: data is a full image for load()
//   odd:  a fixed small map is loaded, then data is appended as records
// Beyond "no crash, no sanitizer report", it checks the store's promises:
// a rejected input leaves the previous map byte-identical; an accepted one
// has counts that match a walk with map_decode_record (the one decoder, which
// find_layer uses too), every record is found by its z, and neighbors name
// the records around it.
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "bulge_map.h"

using namespace bk;

static MapStore store;
static MapLayer found, checked;

#define CHECK(c)     \
  do {               \
    if (!(c)) abort(); \
  } while (0)

// A base map: header (q 50, 0.30 mm, no weights) + two records at z 30 and 60.
static uint16_t base_map(uint8_t *p) {
  static const uint8_t hdr[7] = {'B', 'K', 'M', 1, 0, 50, 30};
  memcpy(p, hdr, 7);
  p[7] = crc8(p, 7);
  uint16_t k = 8;
  for (uint16_t z = 30; z <= 60; z += 30) {
    uint8_t *r = p + k;
    r[0] = (uint8_t)z, r[1] = 0, r[2] = 2, r[3] = 5;
    r[4] = 0x90, r[5] = 0x03, r[6] = 0x00, r[7] = 0x02, r[8] = 0x01;  // (200, 0) then (+1, -1)
    r[9] = crc8(r, 9);
    k += 10;
  }
  return k;
}

struct Snapshot {
  uint16_t used, layers, points, first, last;
  MapInfo info;
  uint8_t bytes[BK_MAP_ARENA_BYTES];
};
static Snapshot snap;

static void take(Snapshot &s) {
  s.used = store.bytes_used();
  s.layers = store.layer_count();
  s.points = store.point_count();
  s.first = store.first_z();
  s.last = store.last_z();
  s.info = store.info();
  memcpy(s.bytes, store.records(), s.used);
}

static void same_as(const Snapshot &s) {
  CHECK(s.used == store.bytes_used());
  CHECK(s.layers == store.layer_count());
  CHECK(s.points == store.point_count());
  CHECK(s.first == store.first_z() && s.last == store.last_z());
  CHECK(memcmp(&s.info, &store.info(), sizeof s.info) == 0);
  CHECK(memcmp(s.bytes, store.records(), s.used) == 0);
}

// Walk the records in force with map_decode_record; compare with find_layer
// and neighbors.
static void verify_store(void) {
  const uint8_t *p = store.records();
  const uint16_t used = store.bytes_used();
  const bool w = store.info().flags & MAP_FLAG_WEIGHTS;
  uint16_t off = 0, layers = 0, points = 0;
  int32_t prev = -1;
  while (off < used) {
    uint16_t size = map_decode_record(p + off, (uint16_t)(used - off), w, checked);
    CHECK(size > 0);
    CHECK(crc8(p + off, (uint16_t)(size - 1)) == p[off + size - 1]);
    CHECK((int32_t)checked.z_cmm > prev);
    if (!off) CHECK(checked.z_cmm == store.first_z());
    int32_t below, above;
    store.neighbors(checked.z_cmm, below, above);
    CHECK(below == prev);
    prev = checked.z_cmm;
    CHECK(store.find_layer(checked.z_cmm, found));
    CHECK(found.z_cmm == checked.z_cmm && found.count == checked.count);
    for (uint8_t i = 0; i < checked.count; i++) {
      CHECK(found.pts[i].x == checked.pts[i].x);
      CHECK(found.pts[i].y == checked.pts[i].y);
      CHECK(found.pts[i].w == checked.pts[i].w);
      CHECK(w || found.pts[i].w == MAP_WEIGHT_FULL);
    }
    layers++;
    points = (uint16_t)(points + checked.count);
    off = (uint16_t)(off + size);
    if (off < used) CHECK(above == (int32_t)(p[off] | p[off + 1] << 8));
    else CHECK(above == INT32_MAX && checked.z_cmm == store.last_z());
  }
  CHECK(off == used);
  CHECK(layers == store.layer_count());
  CHECK(points == store.point_count());
  CHECK(used <= store.capacity());
  CHECK(store.empty() == (used == 0));
  if (!used) CHECK(store.first_z() == 0 && store.last_z() == 0);
  if (used) CHECK(store.z_floor() == store.last_z());
}

// find_layer(z) against a brute-force pick over the records: |dz| * 2 <= h,
// the nearest, the lower one on a tie.
static void probe(int32_t z) {
  const uint8_t *p = store.records();
  const uint16_t used = store.bytes_used();
  const int32_t h = store.info().layer_height_cmm;
  int32_t want = -1, best = 0;
  for (uint16_t off = 0; off < used;) {
    const uint16_t size =
        map_decode_record(p + off, (uint16_t)(used - off), store.info().flags & MAP_FLAG_WEIGHTS, checked);
    CHECK(size > 0);
    const int32_t d = labs((int32_t)checked.z_cmm - z);
    if (2 * d <= h && (want < 0 || d < best)) want = checked.z_cmm, best = d;
    off = (uint16_t)(off + size);
  }
  const bool got = store.find_layer(z, found);
  CHECK(got == (want >= 0));
  if (got) CHECK(found.z_cmm == want);
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  if (size < 1 || size > 4096) return 0;
  const uint8_t mode = data[0];
  const uint8_t *d = data + 1;
  const uint16_t n = (uint16_t)(size - 1);
  // A heap copy of exactly n bytes, so ASan sees any read past the end.
  uint8_t *buf = (uint8_t *)malloc(n ? n : 1);
  memcpy(buf, d, n);
  uint8_t base[64];
  store.clear();
  CHECK(store.load(base, base_map(base)) == MAP_OK);
  take(snap);
  MapError e;
  if (!(mode & 1)) {
    e = store.load(buf, n);
    // load = load_parts on the same bytes; the header counts in error offsets.
    if (n >= MAP_HEADER_BYTES) {
      const uint16_t off = store.error_offset();
      MapStore *other = new MapStore;
      CHECK(other->load_parts(buf, buf + MAP_HEADER_BYTES, (uint16_t)(n - MAP_HEADER_BYTES)) == e);
      CHECK(other->error_offset() == off);
      if (e != MAP_OK && e != MAP_ERR_TOO_LARGE && off) CHECK(off >= MAP_HEADER_BYTES && off < n);
      delete other;
    }
    if (n >= MAP_HEADER_BYTES && n - MAP_HEADER_BYTES > BK_MAP_ARENA_BYTES) CHECK(e == MAP_ERR_TOO_LARGE);
  } else {
    e = store.append(buf, n);
  }
  if (e != MAP_OK) {
    CHECK(e < 0 && e >= MAP_ERR_NO_HEADER);
    same_as(snap);
  } else {
    verify_store();
    // Release at a z taken from the input, then everything must still hold.
    int32_t z = n >= 2 ? (int32_t)(buf[0] | buf[1] << 8) - 100 : 0;
    for (int32_t dz = -40; dz <= 40; dz += 7) probe(z + dz);
    store.release_below(z);
    verify_store();
    if (!store.empty()) CHECK(store.first_z() >= z);
  }
  free(buf);
  return 0;
}
