// Compact bulge map codec: CRCs, varints, the shared vectors (test/vectors),
// every rejection the format names, the layer window, release and append.
#include <string.h>

#include "bktest.h"
#include "bulge_map.h"
#include "../vectors/vectors.h"

#ifdef __AVR__
#define FLASH_COPY(dst, src, n) memcpy_P((dst), (src), (n))
#define FLASH_BYTE(p) pgm_read_byte(p)
#define FLASH_WORD(p) pgm_read_word(p)
#else
#define FLASH_COPY(dst, src, n) memcpy((dst), (src), (n))
#define FLASH_BYTE(p) (*(const uint8_t *)(p))
#define FLASH_WORD(p) (*(const uint16_t *)(p))
#endif

using namespace bk;

// RAM budget (AVR, 8 KiB): store 2 KiB + scratch 2.1 KiB + one layer 0.3 KiB.
static MapStore store;
static MapLayer layer, checked;
static uint8_t scratch[BK_MAP_ARENA_BYTES + 64];

void setUp(void) { store.clear(); }

static uint16_t fetch(const uint8_t *flash, uint16_t n) {
  FLASH_COPY(scratch, flash, n);
  return n;
}
#define FETCH(v) fetch(v, sizeof(v))

// ---- a tiny encoder for cases the vectors do not cover ---------------------------------
static uint8_t hdr_bytes(uint8_t *p, uint8_t flags, uint8_t q, uint8_t lh) {
  p[0] = 'B', p[1] = 'K', p[2] = 'M', p[3] = 1, p[4] = flags, p[5] = q, p[6] = lh;
  p[7] = crc8(p, 7);
  return MAP_HEADER_BYTES;
}
// Record with n points: (x0, y0), then each step (+dx, 0). w != 0: weights w.
static uint16_t rec_bytes(uint8_t *p, uint16_t z, uint8_t n, int32_t x0, int32_t y0, int32_t dx, uint8_t w = 0) {
  uint8_t body[200];
  uint16_t b = varint_write(body, zigzag_encode(x0));
  b += varint_write(body + b, zigzag_encode(y0));
  for (uint8_t i = 1; i < n; i++) {
    b += varint_write(body + b, zigzag_encode(dx));
    b += varint_write(body + b, 0);
  }
  if (w)
    for (uint8_t i = 0; i < n; i++) body[b++] = w;
  uint16_t k = 0;
  p[k++] = (uint8_t)z, p[k++] = (uint8_t)(z >> 8);
  k += varint_write(p + k, n);
  k += varint_write(p + k, b);
  memcpy(p + k, body, b);
  k += b;
  p[k] = crc8(p, k);
  return (uint16_t)(k + 1);
}

// ---- primitives ------------------------------------------------------------------------------
static void test_crc_check_values(void) {
  static const uint8_t check[9] = {'1', '2', '3', '4', '5', '6', '7', '8', '9'};
  TEST_ASSERT_EQUAL_HEX8(0xF4, crc8(check, 9));  // CRC-8/SMBUS
  TEST_ASSERT_EQUAL_HEX32(0xCBF43926UL, crc32_update(0, check, 9));
  TEST_ASSERT_EQUAL_HEX32(0xCBF43926UL, crc32_update(crc32_update(0, check, 4), check + 4, 5));
  TEST_ASSERT_EQUAL_HEX8(crc8(check + 3, 6, crc8(check, 3)), crc8(check, 9));
  TEST_ASSERT_EQUAL_UINT32(bkv_text_cylinder_crc32, crc32_update(0, scratch, FETCH(bkv_text_cylinder)));
  TEST_ASSERT_EQUAL_UINT32(0, crc32_update(0, check, 0));
}

static void test_varint_and_zigzag(void) {
  static const uint32_t vals[] = {0, 1, 127, 128, 16383, 16384, (1UL << 21) - 1};
  static const uint8_t lens[] = {1, 1, 1, 2, 2, 3, 3};
  uint8_t b[4];
  for (uint8_t i = 0; i < 7; i++) {
    TEST_ASSERT_EQUAL_UINT8(lens[i], varint_write(b, vals[i]));
    uint32_t v = 99;
    TEST_ASSERT_EQUAL_INT(lens[i], varint_read(b, lens[i], v));
    TEST_ASSERT_EQUAL_UINT32(vals[i], v);
    if (lens[i] > 1) TEST_ASSERT_EQUAL_INT(0, varint_read(b, (uint16_t)(lens[i] - 1), v));  // truncated
  }
  TEST_ASSERT_EQUAL_UINT8(0, varint_write(b, 1UL << 21));
  static const uint8_t four[4] = {0x80, 0x80, 0x80, 0x01};
  static const uint8_t nonmin[2] = {0x80, 0x00};
  uint32_t v;
  TEST_ASSERT_EQUAL_INT(-1, varint_read(four, 4, v));
  TEST_ASSERT_EQUAL_INT(-1, varint_read(nonmin, 2, v));
  TEST_ASSERT_EQUAL_INT(0, varint_read(four, 0, v));
  TEST_ASSERT_EQUAL_UINT32(0, zigzag_encode(0));
  TEST_ASSERT_EQUAL_UINT32(1, zigzag_encode(-1));
  TEST_ASSERT_EQUAL_UINT32(2, zigzag_encode(1));
  TEST_ASSERT_EQUAL_UINT32(131069UL, zigzag_encode(-65535));
  static const int32_t round[] = {0, -1, 1, 32767, -32768, 65535, -65535};
  for (uint8_t i = 0; i < 7; i++) TEST_ASSERT_EQUAL_INT32(round[i], zigzag_decode(zigzag_encode(round[i])));
}

static void test_error_texts(void) {
  char t[40];
  // The texts are the Python codes (host/bulgekit/bulge/mapformat.py), so both sides name an error alike.
  TEST_ASSERT_EQUAL_INT(10, map_error_copy(MAP_ERR_RECORD_CRC, t, sizeof t));
  TEST_ASSERT_EQUAL_STRING("record_crc", t);
  map_error_copy(MAP_OK, t, sizeof t);
  TEST_ASSERT_EQUAL_STRING("ok", t);
  map_error_copy(MAP_ERR_TRUNCATED, t, sizeof t);
  TEST_ASSERT_EQUAL_STRING("truncated", t);
  map_error_copy(MAP_ERR_NO_HEADER, t, sizeof t);
  TEST_ASSERT_EQUAL_STRING("no_header", t);
  map_error_copy((MapError)-99, t, sizeof t);
  TEST_ASSERT_EQUAL_STRING("unknown", t);
  map_error_copy((MapError)-16, t, sizeof t);
  TEST_ASSERT_EQUAL_STRING("unknown", t);
  map_error_copy((MapError)3, t, sizeof t);
  TEST_ASSERT_EQUAL_STRING("unknown", t);
  // Every code, in enum order: the .code of the Python class of the same error.
  static const char *const py[] = {"truncated",  "magic",      "version",   "flags",  "header_value",
                                   "header_crc", "record_crc", "varint",    "count_zero", "count_max",
                                   "length",     "coord",      "z_order",   "too_large"};
  for (uint8_t i = 0; i < sizeof py / sizeof py[0]; i++) {
    map_error_copy((MapError)-(int8_t)(i + 1), t, sizeof t);
    TEST_ASSERT_EQUAL_STRING(py[i], t);
  }
  TEST_ASSERT_EQUAL_INT(4, map_error_copy(MAP_ERR_TOO_LARGE, t, 5));  // cut to fit, terminated
  TEST_ASSERT_EQUAL_STRING("too_", t);
  // Every code has its own text.
  char u[40];
  for (int8_t a = MAP_ERR_NO_HEADER; a <= MAP_OK; a++) {
    map_error_copy((MapError)a, t, sizeof t);
    TEST_ASSERT_TRUE(t[0] != 0);
    TEST_ASSERT_FALSE(strcmp(t, "unknown") == 0);
    for (int8_t b = (int8_t)(a + 1); b <= MAP_OK; b++) {
      map_error_copy((MapError)b, u, sizeof u);
      TEST_ASSERT_FALSE(strcmp(t, u) == 0);
    }
  }
}

// ---- vectors ----------------------------------------------------------------------------------
// Loads a vector and checks every layer against the points of its JSON.
static void check_vector(const uint8_t *bkm, uint16_t n, const BkvPoint *pts, uint16_t npts, uint8_t q,
                         uint8_t lh, uint8_t flags, uint16_t layers) {
  FLASH_COPY(scratch, bkm, n);
  TEST_ASSERT_EQUAL_INT(MAP_OK, store.load(scratch, n));
  TEST_ASSERT_EQUAL_UINT8(1, store.info().version);
  TEST_ASSERT_EQUAL_UINT8(flags, store.info().flags);
  TEST_ASSERT_EQUAL_UINT8(q, store.info().quantum_um);
  TEST_ASSERT_EQUAL_UINT8(lh, store.info().layer_height_cmm);
  TEST_ASSERT_EQUAL_UINT16(layers, store.layer_count());
  TEST_ASSERT_EQUAL_UINT16(npts, store.point_count());
  TEST_ASSERT_EQUAL_UINT16(n - MAP_HEADER_BYTES, store.bytes_used());
  TEST_ASSERT_EQUAL_MEMORY(scratch + MAP_HEADER_BYTES, store.records(), n - MAP_HEADER_BYTES);
  uint16_t i = 0;
  while (i < npts) {
    BkvPoint p;
    FLASH_COPY(&p, &pts[i], sizeof p);
    TEST_ASSERT_TRUE(store.find_layer(p.z_cmm, layer));
    TEST_ASSERT_EQUAL_UINT16(p.z_cmm, layer.z_cmm);
    for (uint8_t k = 0; k < layer.count; k++, i++) {
      FLASH_COPY(&p, &pts[i], sizeof p);
      TEST_ASSERT_EQUAL_UINT16(layer.z_cmm, p.z_cmm);
      TEST_ASSERT_EQUAL_INT16(p.x, layer.pts[k].x);
      TEST_ASSERT_EQUAL_INT16(p.y, layer.pts[k].y);
      TEST_ASSERT_EQUAL_UINT8(p.w, layer.pts[k].w);
    }
  }
  TEST_ASSERT_EQUAL_UINT16(npts, i);
}
#define CHECK_VECTOR(v, q, lh, fl, layers) \
  check_vector(bkv_##v, sizeof bkv_##v, bkv_##v##_points, sizeof bkv_##v##_points / sizeof(BkvPoint), q, lh, fl, layers)

static void test_vectors_decode_to_their_json_content(void) {
  CHECK_VECTOR(tiny, 50, 30, 0, 1);
  CHECK_VECTOR(weights, 50, 30, 1, 2);
  CHECK_VECTOR(extremes, 10, 255, 0, 2);
  CHECK_VECTOR(full_layer, 50, 30, 1, 1);
  TEST_ASSERT_EQUAL_UINT8(64, layer.count);
  TEST_ASSERT_EQUAL_INT(MAP_OK, store.load(scratch, FETCH(bkv_header_only)));
  TEST_ASSERT_TRUE(store.loaded());
  TEST_ASSERT_TRUE(store.empty());
  TEST_ASSERT_FALSE(store.find_layer(30, layer));
}

static void test_corrupt_vectors_rejected_and_old_map_kept(void) {
  TEST_ASSERT_EQUAL_INT(MAP_OK, store.load(scratch, FETCH(bkv_weights)));
  uint8_t before[64];
  memcpy(before, store.records(), store.bytes_used());
  const uint16_t used = store.bytes_used();
  for (uint8_t i = 0; i < bkv_bad_count; i++) {
    uint16_t off = FLASH_WORD(&bkv_bad[i].offset), n = FLASH_WORD(&bkv_bad[i].len);
    int8_t want = (int8_t)FLASH_BYTE(&bkv_bad[i].error);
    FLASH_COPY(scratch, bkv_bad_blob + off, n);
    int8_t got = store.load(scratch, n);
    if (got != want) {
      TEST_PRINT("  bad vector #");
      bkt_put_uint(i);
      TEST_PRINT(" got ");
      bkt_put_int(got);
      TEST_PRINT(" want ");
      bkt_put_int(want);
      bkt_putc('\n');
    }
    TEST_ASSERT_EQUAL_INT(want, got);
    TEST_ASSERT_EQUAL_UINT16(used, store.bytes_used());
    TEST_ASSERT_EQUAL_UINT16(2, store.layer_count());
    TEST_ASSERT_EQUAL_UINT8(1, store.info().flags);
    TEST_ASSERT_EQUAL_MEMORY(before, store.records(), used);
  }
}

static void test_text_cylinder_every_layer(void) {
  uint16_t n = FETCH(bkv_text_cylinder);
  TEST_ASSERT_EQUAL_INT(MAP_OK, store.load(scratch, n));
  TEST_ASSERT_EQUAL_UINT16(34, store.layer_count());
  TEST_ASSERT_EQUAL_UINT16(484, store.point_count());
  // Walk the records in the source bytes and find each layer from z - h/2 to z + h/2.
  uint16_t off = MAP_HEADER_BYTES, layers = 0, points = 0;
  while (off < n) {
    uint16_t z = (uint16_t)(scratch[off] | scratch[off + 1] << 8);
    uint16_t size = map_decode_record(scratch + off, (uint16_t)(n - off), false, checked);
    TEST_ASSERT_TRUE(size > 0);
    // find_layer picks this record and decodes it as map_decode_record does.
    TEST_ASSERT_TRUE(store.find_layer(z, layer));
    TEST_ASSERT_EQUAL_UINT8(checked.count, layer.count);
    for (uint8_t k = 0; k < checked.count; k++) {
      TEST_ASSERT_EQUAL_INT16(checked.pts[k].x, layer.pts[k].x);
      TEST_ASSERT_EQUAL_INT16(checked.pts[k].y, layer.pts[k].y);
      TEST_ASSERT_EQUAL_UINT8(255, layer.pts[k].w);
    }
    TEST_ASSERT_TRUE(crc8(scratch + off, (uint16_t)(size - 1)) == scratch[off + size - 1]);
    if (!layers) TEST_ASSERT_EQUAL_UINT16(z, store.first_z());
    static const int8_t dz[] = {-14, -1, 0, 1, 15};  // -15 ties with z - 30: lower wins
    for (uint8_t k = 0; k < 5; k++) {
      MapLayer &got = layer;
      TEST_ASSERT_TRUE(store.find_layer((int32_t)z + dz[k], got));
      TEST_ASSERT_EQUAL_UINT16(z, got.z_cmm);
    }
    points = (uint16_t)(points + layer.count);
    layers++;
    off = (uint16_t)(off + size);
    if (off >= n) TEST_ASSERT_EQUAL_UINT16(z, store.last_z());
  }
  TEST_ASSERT_EQUAL_UINT16(n, off);
  TEST_ASSERT_EQUAL_UINT16(34, layers);
  TEST_ASSERT_EQUAL_UINT16(484, points);
  TEST_ASSERT_FALSE(store.find_layer(store.first_z() - 16, layer));
  TEST_ASSERT_FALSE(store.find_layer(store.last_z() + 16, layer));
  TEST_PRINT("  text_cylinder: ");
  bkt_put_uint(n);
  TEST_PRINT(" bytes, 484 points: ");
  bkt_put_float((double)n / 484.0, 2);
  TEST_PRINT(" bytes/point\n");
}

// Every truncation and every single-bit flip of a vector is caught.
static void test_mutations_rejected(void) {
  const uint16_t n = FETCH(bkv_weights);
  uint8_t orig[40];
  memcpy(orig, scratch, n);
  const uint16_t rec2 = (uint16_t)(MAP_HEADER_BYTES + map_decode_record(orig + 8, n - 8, true, layer));
  for (uint16_t cut = 0; cut < n; cut++) {
    MapError e = store.load(orig, cut);
    if (cut == MAP_HEADER_BYTES || cut == rec2) TEST_ASSERT_EQUAL_INT(MAP_OK, e);  // whole records
    else TEST_ASSERT_EQUAL_INT(MAP_ERR_TRUNCATED, e);
  }
  for (uint16_t i = 0; i < n; i++)
    for (uint8_t bit = 0; bit < 8; bit++) {
      memcpy(scratch, orig, n);
      scratch[i] ^= (uint8_t)(1 << bit);
      TEST_ASSERT_TRUE(store.load(scratch, n) != MAP_OK);
    }
}

// ---- rules the vectors do not reach ------------------------------------------------------------
static void test_coordinate_limits_from_deltas(void) {
  uint16_t k = hdr_bytes(scratch, 0, 50, 30);
  k += rec_bytes(scratch + k, 30, 2, 0, -32768, 0);
  TEST_ASSERT_EQUAL_INT(MAP_OK, store.load(scratch, k));
  // y0 = -32769 is one below int16.
  k = hdr_bytes(scratch, 0, 50, 30);
  k += rec_bytes(scratch + k, 30, 1, 0, -32769, 0);
  TEST_ASSERT_EQUAL_INT(MAP_ERR_COORD, store.load(scratch, k));
  // A delta that walks below int16 on the 3rd point.
  k = hdr_bytes(scratch, 0, 50, 30);
  k += rec_bytes(scratch + k, 30, 3, -30000, 0, -1500);
  TEST_ASSERT_EQUAL_INT(MAP_ERR_COORD, store.load(scratch, k));
  k = hdr_bytes(scratch, 0, 50, 30);
  k += rec_bytes(scratch + k, 30, 2, -32768, 0, 65535);  // corner to corner: 3-byte delta
  TEST_ASSERT_EQUAL_INT(MAP_OK, store.load(scratch, k));
  TEST_ASSERT_TRUE(store.find_layer(30, layer));
  TEST_ASSERT_EQUAL_INT16(32767, layer.pts[1].x);
}

static void test_point_count_limits(void) {
  uint16_t k = hdr_bytes(scratch, 1, 50, 30);
  k += rec_bytes(scratch + k, 30, BK_LAYER_POINTS_MAX, 5, 5, 1, 7);
  TEST_ASSERT_EQUAL_INT(MAP_OK, store.load(scratch, k));
  TEST_ASSERT_TRUE(store.find_layer(30, layer));
  TEST_ASSERT_EQUAL_UINT8(BK_LAYER_POINTS_MAX, layer.count);
  TEST_ASSERT_EQUAL_UINT8(7, layer.pts[BK_LAYER_POINTS_MAX - 1].w);
  TEST_ASSERT_EQUAL_INT16(5 + BK_LAYER_POINTS_MAX - 1, layer.pts[BK_LAYER_POINTS_MAX - 1].x);
  k = hdr_bytes(scratch, 1, 50, 30);
  k += rec_bytes(scratch + k, 30, BK_LAYER_POINTS_MAX + 1, 5, 5, 1, 7);
  TEST_ASSERT_EQUAL_INT(MAP_ERR_COUNT_MAX, store.load(scratch, k));
}

static void test_layer_window(void) {
  uint16_t k = hdr_bytes(scratch, 0, 50, 30);
  k += rec_bytes(scratch + k, 30, 1, 1, 0, 0);
  k += rec_bytes(scratch + k, 60, 1, 2, 0, 0);
  k += rec_bytes(scratch + k, 90, 1, 3, 0, 0);
  k += rec_bytes(scratch + k, 180, 1, 4, 0, 0);
  TEST_ASSERT_EQUAL_INT(MAP_OK, store.load(scratch, k));
  static const int16_t z_in[] = {15, 30, 44, 45, 46, 75, 76, 105, 106, 134, 135, 165, 195, 196, 14, -5};
  static const int8_t x_out[] = {1, 1, 1, 1, 2, 2, 3, 3, 0, 0, 0, 4, 4, 0, 0, 0};
  for (uint8_t i = 0; i < sizeof z_in / sizeof z_in[0]; i++) {
    bool found = store.find_layer(z_in[i], layer);
    TEST_ASSERT_EQUAL_INT(x_out[i] != 0, found);
    if (found) TEST_ASSERT_EQUAL_INT(x_out[i], layer.pts[0].x);
  }
  // Odd layer height: within 12.5 means |dz| <= 12.
  k = hdr_bytes(scratch, 0, 50, 25);
  k += rec_bytes(scratch + k, 100, 1, 1, 0, 0);
  TEST_ASSERT_EQUAL_INT(MAP_OK, store.load(scratch, k));
  TEST_ASSERT_TRUE(store.find_layer(112, layer));
  TEST_ASSERT_FALSE(store.find_layer(113, layer));
  TEST_ASSERT_TRUE(store.find_layer(88, layer));
  TEST_ASSERT_FALSE(store.find_layer(87, layer));
}

static void test_release_and_append(void) {
  uint16_t k = hdr_bytes(scratch, 0, 50, 30);
  uint16_t sizes[5];
  for (uint8_t i = 0; i < 5; i++) {
    sizes[i] = rec_bytes(scratch + k, (uint16_t)(30 * (i + 1)), (uint8_t)(i + 1), 100, 100, 3);
    k = (uint16_t)(k + sizes[i]);
  }
  TEST_ASSERT_EQUAL_INT(MAP_OK, store.load(scratch, k));
  TEST_ASSERT_EQUAL_UINT16(15, store.point_count());
  store.release_below(30);  // nothing below the first layer
  TEST_ASSERT_EQUAL_UINT16(5, store.layer_count());
  store.release_below(89);  // drops 30 and 60
  TEST_ASSERT_EQUAL_UINT16(3, store.layer_count());
  TEST_ASSERT_EQUAL_UINT16(12, store.point_count());
  TEST_ASSERT_EQUAL_UINT16(90, store.first_z());
  TEST_ASSERT_EQUAL_UINT16(k - 8 - sizes[0] - sizes[1], store.bytes_used());
  TEST_ASSERT_EQUAL_MEMORY(scratch + 8 + sizes[0] + sizes[1], store.records(), store.bytes_used());
  TEST_ASSERT_FALSE(store.find_layer(60, layer));
  TEST_ASSERT_TRUE(store.find_layer(90, layer));
  TEST_ASSERT_EQUAL_UINT8(3, layer.count);
  // Appends continue above 150, even once everything is released.
  store.release_below(1000);
  TEST_ASSERT_TRUE(store.empty());
  TEST_ASSERT_TRUE(store.loaded());
  TEST_ASSERT_EQUAL_UINT16(0, store.bytes_used());
  uint16_t r = rec_bytes(scratch, 150, 2, 0, 0, 1);
  TEST_ASSERT_EQUAL_INT(MAP_ERR_Z_ORDER, store.append(scratch, r));
  r = rec_bytes(scratch, 180, 2, 0, 0, 1);
  uint16_t r2 = rec_bytes(scratch + r, 210, 3, 0, 0, 1);
  scratch[r + r2 - 1] ^= 1;  // second record corrupt: neither goes in
  TEST_ASSERT_EQUAL_INT(MAP_ERR_RECORD_CRC, store.append(scratch, (uint16_t)(r + r2)));
  TEST_ASSERT_EQUAL_UINT16(r, store.error_offset());
  TEST_ASSERT_TRUE(store.empty());
  scratch[r + r2 - 1] ^= 1;
  TEST_ASSERT_EQUAL_INT(MAP_OK, store.append(scratch, (uint16_t)(r + r2)));
  TEST_ASSERT_EQUAL_UINT16(2, store.layer_count());
  TEST_ASSERT_EQUAL_UINT16(180, store.first_z());
  TEST_ASSERT_EQUAL_UINT16(210, store.last_z());
  TEST_ASSERT_EQUAL_UINT16(5, store.point_count());
  TEST_ASSERT_TRUE(store.find_layer(210, layer));
  TEST_ASSERT_EQUAL_UINT8(3, layer.count);
  // Without a header there is nothing to append to.
  store.clear();
  TEST_ASSERT_EQUAL_INT(MAP_ERR_NO_HEADER, store.append(scratch, r));
  TEST_ASSERT_EQUAL_INT(-1, store.z_floor());
}

// Fills the arena to exactly BK_MAP_ARENA_BYTES of records, then one byte more.
static uint16_t fill_records(uint8_t *p, uint16_t total, uint16_t &z) {
  uint16_t k = 0;
  while (total - k > 131) {  // 60 one-byte deltas: 125-byte records
    k += rec_bytes(p + k, z, 60, 0, 0, 1);
    z += 30;
  }
  uint16_t rest = (uint16_t)(total - k);  // 8..131: odd sizes with a 1-byte x0, even with 2
  if (rest & 1) k += rec_bytes(p + k, z, (uint8_t)((rest - 5) / 2), 0, 0, 1);
  else k += rec_bytes(p + k, z, (uint8_t)((rest - 6) / 2), 100, 0, 1);
  z += 30;
  return k;
}

static void test_capacity_exact_and_oversize(void) {
  uint16_t z = 30;
  uint16_t k = hdr_bytes(scratch, 0, 50, 30);
  k += fill_records(scratch + k, BK_MAP_ARENA_BYTES, z);
  TEST_ASSERT_EQUAL_UINT16(BK_MAP_ARENA_BYTES + 8, k);
  TEST_ASSERT_EQUAL_INT(MAP_OK, store.load(scratch, k));
  TEST_ASSERT_EQUAL_UINT16(0, store.free_bytes());
  const uint16_t layers = store.layer_count();
  // A full arena takes no append, and keeps its map.
  uint16_t r = rec_bytes(scratch, z, 1, 0, 0, 0);
  TEST_ASSERT_EQUAL_INT(MAP_ERR_TOO_LARGE, store.append(scratch, r));
  TEST_ASSERT_EQUAL_UINT16(layers, store.layer_count());
  TEST_ASSERT_EQUAL_INT(MAP_ERR_TOO_LARGE, store.stage_open(1));
  // Releasing the first layer makes room.
  store.release_below(31);
  TEST_ASSERT_EQUAL_INT(MAP_OK, store.append(scratch, r));
  TEST_ASSERT_EQUAL_UINT16(layers, store.layer_count());
  const uint16_t used = store.bytes_used();
  TEST_ASSERT_EQUAL_UINT16(BK_MAP_ARENA_BYTES - 125 + r, used);
  // One byte over the arena: refused whole, old map kept.
  z = 30;
  k = hdr_bytes(scratch, 0, 50, 30);
  k += fill_records(scratch + k, BK_MAP_ARENA_BYTES + 1, z);
  TEST_ASSERT_EQUAL_INT(MAP_ERR_TOO_LARGE, store.load(scratch, k));
  TEST_ASSERT_EQUAL_UINT16(layers, store.layer_count());
  TEST_ASSERT_EQUAL_UINT16(used, store.bytes_used());
}

static void test_header_field_order(void) {
  // Version 2 with a valid CRC reads as a version error, with a broken CRC as corruption.
  uint8_t h[8];
  hdr_bytes(h, 0, 50, 30);
  h[3] = 2;
  h[7] = crc8(h, 7);
  TEST_ASSERT_EQUAL_INT(MAP_ERR_VERSION, store.load(h, 8));
  h[7] ^= 1;
  TEST_ASSERT_EQUAL_INT(MAP_ERR_HEADER_CRC, store.load(h, 8));
  hdr_bytes(h, 0, 50, 0);  // layer height 0
  TEST_ASSERT_EQUAL_INT(MAP_ERR_HEADER_VALUE, store.load(h, 8));
  hdr_bytes(h, 0x80, 50, 30);
  TEST_ASSERT_EQUAL_INT(MAP_ERR_FLAGS, store.load(h, 8));
  TEST_ASSERT_FALSE(store.loaded());
}

static void test_staging_moves_with_release(void) {
  uint16_t k = hdr_bytes(scratch, 0, 50, 30);
  k += rec_bytes(scratch + k, 30, 4, 0, 0, 2);
  k += rec_bytes(scratch + k, 60, 4, 0, 0, 2);
  TEST_ASSERT_EQUAL_INT(MAP_OK, store.load(scratch, k));
  uint16_t r = rec_bytes(scratch, 90, 5, 9, 9, 1);
  TEST_ASSERT_EQUAL_INT(MAP_OK, store.stage_open(r));
  memcpy(store.stage_data(), scratch, r);
  store.release_below(60);  // the staged bytes must follow the records down
  TEST_ASSERT_EQUAL_UINT16(r, store.stage_size());
  TEST_ASSERT_EQUAL_MEMORY(scratch, store.stage_data(), r);
  TEST_ASSERT_EQUAL_INT(MAP_OK, store.append(store.stage_data(), r));
  TEST_ASSERT_EQUAL_UINT16(0, store.stage_size());
  TEST_ASSERT_EQUAL_UINT16(2, store.layer_count());
  TEST_ASSERT_TRUE(store.find_layer(90, layer));
  TEST_ASSERT_EQUAL_INT16(13, layer.pts[4].x);
}

int main(void) {
  UNITY_BEGIN();
  RUN_TEST(test_crc_check_values);
  RUN_TEST(test_varint_and_zigzag);
  RUN_TEST(test_error_texts);
  RUN_TEST(test_vectors_decode_to_their_json_content);
  RUN_TEST(test_corrupt_vectors_rejected_and_old_map_kept);
  RUN_TEST(test_text_cylinder_every_layer);
  RUN_TEST(test_mutations_rejected);
  RUN_TEST(test_coordinate_limits_from_deltas);
  RUN_TEST(test_point_count_limits);
  RUN_TEST(test_layer_window);
  RUN_TEST(test_release_and_append);
  RUN_TEST(test_capacity_exact_and_oversize);
  RUN_TEST(test_header_field_order);
  RUN_TEST(test_staging_moves_with_release);
  return UNITY_END();
}
