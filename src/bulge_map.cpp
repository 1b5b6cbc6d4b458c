// Compact bulge map v1 codec and store. See bulge_map.h and docs/map-format.md.
#include "bulge_map.h"

#include <string.h>

#include "flash_text.h"

namespace bk {

// Nibble tables (16 entries each, 80 bytes of flash instead of 1.25 KiB for
// byte tables): two lookups a byte. The CRCs only run when a map is uploaded
// (M721 chunks and commit), never per move, so the flash matters more here.
// CRC-8 poly 0x07: crc8_nib[i] is the CRC register after shifting the nibble i
// (in the high half) out.
static const uint8_t crc8_nib[16] BK_FLASH = {
    0x00, 0x07, 0x0E, 0x09, 0x1C, 0x1B, 0x12, 0x15, 0x38, 0x3F, 0x36, 0x31, 0x24, 0x23, 0x2A, 0x2D,
};

// CRC-32 IEEE, reflected poly 0xEDB88320: crc32_nib[i] is the register after
// shifting the nibble i (in the low half) out.
static const uint32_t crc32_nib[16] BK_FLASH = {
    0x00000000UL, 0x1DB71064UL, 0x3B6E20C8UL, 0x26D930ACUL,
    0x76DC4190UL, 0x6B6B51F4UL, 0x4DB26158UL, 0x5005713CUL,
    0xEDB88320UL, 0xF00F9344UL, 0xD6D6A3E8UL, 0xCB61B38CUL,
    0x9B64C2B0UL, 0x86D3D2D4UL, 0xA00AE278UL, 0xBDBDF21CUL,
};

uint8_t crc8(const uint8_t *p, uint16_t n, uint8_t crc) {
  while (n--) {
    crc ^= *p++;
    crc = (uint8_t)(crc << 4) ^ BK_RD8(&crc8_nib[crc >> 4]);
    crc = (uint8_t)(crc << 4) ^ BK_RD8(&crc8_nib[crc >> 4]);
  }
  return crc;
}

uint32_t crc32_update(uint32_t crc, const uint8_t *p, uint16_t n) {
  crc = ~crc;
  while (n--) {
    crc ^= *p++;
    crc = (crc >> 4) ^ BK_RD32(&crc32_nib[crc & 15]);
    crc = (crc >> 4) ^ BK_RD32(&crc32_nib[crc & 15]);
  }
  return ~crc;
}

// ---- error texts (flash on AVR) -------------------------------------------------
static const char et_ok[] BK_FLASH = "ok";
static const char et_truncated[] BK_FLASH = "truncated";
static const char et_magic[] BK_FLASH = "bad magic (not a BKM map)";
static const char et_version[] BK_FLASH = "unsupported version";
static const char et_flags[] BK_FLASH = "unknown flag bits";
static const char et_hvalue[] BK_FLASH = "quantum or layer height is 0";
static const char et_hcrc[] BK_FLASH = "header CRC mismatch";
static const char et_rcrc[] BK_FLASH = "record CRC mismatch";
static const char et_varint[] BK_FLASH = "over-long varint";
static const char et_nzero[] BK_FLASH = "layer with 0 points";
static const char et_nmax[] BK_FLASH = "too many points in a layer";
static const char et_length[] BK_FLASH = "record length mismatch";
static const char et_coord[] BK_FLASH = "coordinate out of int16 range";
static const char et_zorder[] BK_FLASH = "z not increasing";
static const char et_large[] BK_FLASH = "map too large";
static const char et_noheader[] BK_FLASH = "no map loaded to append to";
static const char et_unknown[] BK_FLASH = "unknown error";
static const char *const error_texts[] BK_FLASH = {
    et_ok,    et_truncated, et_magic, et_version, et_flags, et_hvalue, et_hcrc, et_rcrc,
    et_varint, et_nzero,    et_nmax,  et_length,  et_coord, et_zorder, et_large, et_noheader,
};

const char *map_error_text(MapError e) {
  int8_t i = (int8_t)-e;
  if (i < 0 || i >= (int8_t)(sizeof(error_texts) / sizeof(error_texts[0]))) return et_unknown;
  return BK_RDPTR(&error_texts[i]);
}

uint8_t map_error_copy(MapError e, char *buf, uint8_t size) {
  if (!size) return 0;
  const char *s = map_error_text(e);
  uint8_t n = 0;
  char c;
  while (n + 1 < size && (c = (char)BK_RD8((const uint8_t *)s + n)) != 0) buf[n++] = c;
  buf[n] = 0;
  return n;
}

// ---- varints ----------------------------------------------------------------------
int8_t varint_read(const uint8_t *p, uint16_t avail, uint32_t &out) {
  if (!avail) return 0;
  uint8_t b = p[0];
  if (!(b & 0x80)) {  // the common case: one byte
    out = b;
    return 1;
  }
  uint32_t v = b & 0x7F;
  for (uint8_t i = 1; i < MAP_VARINT_MAX_BYTES; i++) {
    if (i >= avail) return 0;
    b = p[i];
    v |= (uint32_t)(b & 0x7F) << (7 * i);
    if (!(b & 0x80)) {
      if (!b) return -1;  // a zero top group: not minimal
      out = v;
      return (int8_t)(i + 1);
    }
  }
  return -1;  // a continuation bit on the third byte
}

uint8_t varint_write(uint8_t *p, uint32_t v) {
  if (v >= (1UL << 21)) return 0;
  uint8_t n = 0;
  while (v >= 0x80) {
    p[n++] = (uint8_t)(v | 0x80);
    v >>= 7;
  }
  p[n++] = (uint8_t)v;
  return n;
}

// ---- records -------------------------------------------------------------------------
// Check order (the Python decoder follows it, so a corrupt vector gets the same
// error on both sides): z present, n varint and range, len varint, body + CRC
// present, CRC, body contents and length, then z order (by the caller).
struct RecordHead {
  uint16_t z;
  uint8_t n;
  uint16_t body;  // offset of the body from the record start
  uint16_t len;   // body length
  uint16_t size;  // whole record including the CRC byte
};

static MapError read_head(const uint8_t *p, uint16_t avail, RecordHead &h) {
  if (avail < 2) return MAP_ERR_TRUNCATED;
  h.z = (uint16_t)(p[0] | ((uint16_t)p[1] << 8));
  uint16_t off = 2;
  uint32_t v;
  int8_t r = varint_read(p + off, (uint16_t)(avail - off), v);
  if (r == 0) return MAP_ERR_TRUNCATED;
  if (r < 0) return MAP_ERR_VARINT;
  if (v == 0) return MAP_ERR_COUNT_ZERO;
  if (v > BK_LAYER_POINTS_MAX) return MAP_ERR_COUNT_MAX;
  h.n = (uint8_t)v;
  off = (uint16_t)(off + r);
  r = varint_read(p + off, (uint16_t)(avail - off), v);
  if (r == 0) return MAP_ERR_TRUNCATED;
  if (r < 0) return MAP_ERR_VARINT;
  off = (uint16_t)(off + r);
  if (v + 1 > (uint32_t)(avail - off)) return MAP_ERR_TRUNCATED;  // body + CRC byte
  h.body = off;
  h.len = (uint16_t)v;
  h.size = (uint16_t)(off + v + 1);
  return MAP_OK;
}

// Parses the body of a record whose head is h; fills out when given.
static MapError read_body(const uint8_t *p, const RecordHead &h, bool weights, MapLayer *out) {
  const uint8_t *b = p + h.body;
  uint16_t left = h.len;
  int32_t x = 0, y = 0;
  for (uint8_t i = 0; i < h.n; i++) {
    uint32_t u;
    int8_t r = varint_read(b, left, u);
    if (r == 0) return MAP_ERR_LENGTH;  // body ends before the points do
    if (r < 0) return MAP_ERR_VARINT;
    b += r;
    left = (uint16_t)(left - r);
    x += zigzag_decode(u);
    r = varint_read(b, left, u);
    if (r == 0) return MAP_ERR_LENGTH;
    if (r < 0) return MAP_ERR_VARINT;
    b += r;
    left = (uint16_t)(left - r);
    y += zigzag_decode(u);
    if (x < -32768 || x > 32767 || y < -32768 || y > 32767) return MAP_ERR_COORD;
    if (out) {
      out->pts[i].x = (int16_t)x;
      out->pts[i].y = (int16_t)y;
      out->pts[i].w = MAP_WEIGHT_FULL;
    }
  }
  if (weights) {
    if (left < h.n) return MAP_ERR_LENGTH;
    if (out)
      for (uint8_t i = 0; i < h.n; i++) out->pts[i].w = b[i];
    left = (uint16_t)(left - h.n);
  }
  if (left) return MAP_ERR_LENGTH;  // bytes after the last field
  if (out) {
    out->z_cmm = h.z;
    out->count = h.n;
  }
  return MAP_OK;
}

uint16_t map_decode_record(const uint8_t *p, uint16_t avail, bool weights, MapLayer &out) {
  RecordHead h;
  if (read_head(p, avail, h) != MAP_OK) return 0;
  if (read_body(p, h, weights, &out) != MAP_OK) return 0;
  return h.size;
}

MapError map_parse_header(const uint8_t *p, uint16_t len, MapInfo &info) {
  if (len < MAP_HEADER_BYTES) return MAP_ERR_TRUNCATED;
  if (p[0] != 'B' || p[1] != 'K' || p[2] != 'M') return MAP_ERR_MAGIC;
  // CRC before the field checks: a flipped bit reads as corruption, while a
  // well-formed header from a newer host reads as "unsupported version".
  if (crc8(p, 7) != p[7]) return MAP_ERR_HEADER_CRC;
  if (p[3] != MAP_VERSION) return MAP_ERR_VERSION;
  if (p[4] & (uint8_t)~MAP_FLAG_WEIGHTS) return MAP_ERR_FLAGS;
  if (!p[5] || !p[6]) return MAP_ERR_HEADER_VALUE;
  info.version = p[3];
  info.flags = p[4];
  info.quantum_um = p[5];
  info.layer_height_cmm = p[6];
  return MAP_OK;
}

MapError map_scan(const uint8_t *p, uint16_t len, bool with_header, MapInfo &info, int32_t after_z,
                  MapScan &scan) {
  uint16_t off = 0;
  scan.layers = scan.points = scan.first_z = scan.last_z = 0;
  scan.error_offset = 0;
  MapInfo hi = info;
  if (with_header) {
    MapError e = map_parse_header(p, len, hi);
    if (e != MAP_OK) return e;
    off = MAP_HEADER_BYTES;
  }
  const bool weights = hi.flags & MAP_FLAG_WEIGHTS;
  int32_t prev_z = after_z;
  while (off < len) {
    scan.error_offset = off;
    RecordHead h;
    MapError e = read_head(p + off, (uint16_t)(len - off), h);
    if (e != MAP_OK) return e;
    if (crc8(p + off, (uint16_t)(h.size - 1)) != p[off + h.size - 1]) return MAP_ERR_RECORD_CRC;
    e = read_body(p + off, h, weights, 0);
    if (e != MAP_OK) return e;
    if ((int32_t)h.z <= prev_z) return MAP_ERR_Z_ORDER;
    prev_z = h.z;
    if (!scan.layers) scan.first_z = h.z;
    scan.last_z = h.z;
    scan.layers++;
    scan.points = (uint16_t)(scan.points + h.n);
    off = (uint16_t)(off + h.size);
  }
  scan.error_offset = 0;
  if (with_header) info = hi;
  return MAP_OK;
}

// ---- store ------------------------------------------------------------------------------
void MapStore::clear() {
  used_ = layers_ = points_ = first_z_ = last_z_ = 0;
  z_floor_ = -1;
  stage_size_ = 0;
  error_offset_ = 0;
  info_.version = info_.flags = info_.quantum_um = info_.layer_height_cmm = 0;
}

MapError MapStore::load(const uint8_t *data, uint16_t len) {
  if (len < MAP_HEADER_BYTES) {
    error_offset_ = 0;
    return MAP_ERR_TRUNCATED;
  }
  return load_parts(data, data + MAP_HEADER_BYTES, (uint16_t)(len - MAP_HEADER_BYTES));
}

MapError MapStore::load_parts(const uint8_t *header, const uint8_t *records, uint16_t len) {
  error_offset_ = 0;
  if (len > BK_MAP_ARENA_BYTES) return MAP_ERR_TOO_LARGE;
  MapInfo info = info_;
  MapError e = map_parse_header(header, MAP_HEADER_BYTES, info);
  if (e != MAP_OK) return e;
  MapScan s;
  e = map_scan(records, len, false, info, -1, s);
  if (e != MAP_OK) {
    error_offset_ = (uint16_t)(s.error_offset + MAP_HEADER_BYTES);
    return e;
  }
  used_ = len;
  memmove(arena_, records, len);  // records may lie in the arena (staging)
  info_ = info;
  layers_ = s.layers;
  points_ = s.points;
  first_z_ = s.first_z;
  last_z_ = s.last_z;
  z_floor_ = s.layers ? (int32_t)s.last_z : -1;
  stage_size_ = 0;
  return MAP_OK;
}

MapError MapStore::append(const uint8_t *records, uint16_t len) {
  error_offset_ = 0;
  if (!loaded()) return MAP_ERR_NO_HEADER;
  if (len > free_bytes()) return MAP_ERR_TOO_LARGE;
  MapInfo info = info_;
  MapScan s;
  MapError e = map_scan(records, len, false, info, z_floor_, s);
  if (e != MAP_OK) {
    error_offset_ = s.error_offset;
    return e;
  }
  memmove(arena_ + used_, records, len);  // a no-op when committing the staging area
  used_ = (uint16_t)(used_ + len);
  if (s.layers) {
    if (!layers_) first_z_ = s.first_z;
    last_z_ = s.last_z;
    z_floor_ = s.last_z;
    layers_ = (uint16_t)(layers_ + s.layers);
    points_ = (uint16_t)(points_ + s.points);
  }
  stage_size_ = 0;
  return MAP_OK;
}

// ---- trusted fast paths --------------------------------------------------------------
// Records in the arena were validated in full on entry (load/append), and
// release_below moves whole records, so the layer-change path can skip the
// checks: 16-bit maths, one-byte varints inline. x + dx is done modulo 2^16,
// which gives the right int16 because validation proved the true sum fits.
// This roughly halves find_layer's cycles on AVR (see test_bench_map).
struct FastHead {
  uint16_t z;
  uint8_t n;
  uint8_t body;  // offset of the body
  uint16_t size;
};

static inline void fast_head(const uint8_t *p, FastHead &h) {
  h.z = (uint16_t)(p[0] | ((uint16_t)p[1] << 8));
  uint8_t o = 2, b = p[o++];
  h.n = b & 0x7F;
  if (b & 0x80) h.n = (uint8_t)(h.n | (p[o++] << 7));
  b = p[o++];
  uint16_t len = b & 0x7F;
  if (b & 0x80) {
    b = p[o++];
    len |= (uint16_t)(b & 0x7F) << 7;
    if (b & 0x80) len |= (uint16_t)p[o++] << 14;
  }
  h.body = o;
  h.size = (uint16_t)(o + len + 1);
}

static inline const uint8_t *fast_delta(const uint8_t *p, uint16_t &d) {
  uint8_t b = *p++;
  if (!(b & 0x80)) {
    d = (uint16_t)((uint8_t)(b >> 1) ^ (uint16_t)-(int16_t)(b & 1));
    return p;
  }
  uint16_t u = b & 0x7F;
  b = *p++;
  if (!(b & 0x80)) {
    u |= (uint16_t)b << 7;
    d = (uint16_t)((u >> 1) ^ (uint16_t)-(int16_t)(u & 1));
    return p;
  }
  uint32_t v = u | ((uint32_t)(b & 0x7F) << 7) | ((uint32_t)*p++ << 14);
  d = (uint16_t)((v >> 1) ^ (uint32_t) - (int32_t)(v & 1));
  return p;
}

static void fast_decode(const uint8_t *p, const FastHead &h, bool weights, MapLayer &out) {
  const uint8_t *b = p + h.body;
  uint16_t x = 0, y = 0, d;
  MapPoint *pt = out.pts;
  for (uint8_t i = 0; i < h.n; i++, pt++) {
    b = fast_delta(b, d);
    x = (uint16_t)(x + d);
    b = fast_delta(b, d);
    y = (uint16_t)(y + d);
    pt->x = (int16_t)x;
    pt->y = (int16_t)y;
    pt->w = MAP_WEIGHT_FULL;
  }
  if (weights)
    for (uint8_t i = 0; i < h.n; i++) out.pts[i].w = b[i];
  out.z_cmm = h.z;
  out.count = h.n;
}

bool MapStore::find_layer(int32_t z_cmm, MapLayer &out) const {
  // Compare in 16 bits: z outside 0..65535 can only match near the ends.
  const int32_t h = info_.layer_height_cmm;
  uint16_t off = 0, best = 0xFFFF;
  int32_t best_d = 0;
  FastHead fh, bh;
  while (off < used_) {
    fast_head(arena_ + off, fh);
    if (fh.size > used_ - off) return false;  // cannot happen with validated records
    int32_t d = (int32_t)fh.z - z_cmm;
    if (d > 0 && 2 * d > h) break;  // z only grows from here
    if (d < 0) d = -d;
    if (2 * d <= h && (best == 0xFFFF || d < best_d)) {
      best = off;
      best_d = d;
      bh = fh;
    }
    off = (uint16_t)(off + fh.size);
  }
  if (best == 0xFFFF) return false;
  fast_decode(arena_ + best, bh, info_.flags & MAP_FLAG_WEIGHTS, out);
  return true;
}

void MapStore::neighbors(int32_t z_cmm, int32_t &below, int32_t &above) const {
  below = -1;
  above = INT32_MAX;
  uint16_t off = 0;
  FastHead fh;
  while (off < used_) {
    fast_head(arena_ + off, fh);
    if (fh.size > used_ - off) return;  // cannot happen with validated records
    if ((int32_t)fh.z < z_cmm) {
      below = fh.z;
    } else if ((int32_t)fh.z > z_cmm) {
      above = fh.z;
      return;
    }
    off = (uint16_t)(off + fh.size);
  }
}

void MapStore::release_below(int32_t z_cmm) {
  uint16_t off = 0, layers = 0, points = 0;
  while (off < used_) {
    RecordHead rh;
    if (read_head(arena_ + off, (uint16_t)(used_ - off), rh) != MAP_OK) break;
    if ((int32_t)rh.z >= z_cmm) {
      first_z_ = rh.z;
      break;
    }
    layers++;
    points = (uint16_t)(points + rh.n);
    off = (uint16_t)(off + rh.size);
  }
  if (!off) return;
  // Staged upload bytes sit right after the records and move with them.
  memmove(arena_, arena_ + off, (uint16_t)(used_ - off + stage_size_));
  used_ = (uint16_t)(used_ - off);
  layers_ = (uint16_t)(layers_ - layers);
  points_ = (uint16_t)(points_ - points);
  if (!layers_) first_z_ = last_z_ = 0;  // z_floor_ keeps the append order
}

MapError MapStore::stage_open(uint16_t size) {
  stage_size_ = 0;
  if (size > free_bytes()) return MAP_ERR_TOO_LARGE;
  stage_size_ = size;
  return MAP_OK;
}

}  // namespace bk
