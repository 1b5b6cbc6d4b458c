// Compact bulge map v1 codec and store. See bulge_map.h and docs/reference/map-format.md.
#include "bulge_map.h"

#include <string.h>

#include "flash_text.h"

namespace bk {

// Bit at a time: smaller than any table, and on AVR about as fast as the nibble
// tables were (no flash reads; the bit tests are written in 8 bits for avr-gcc).
// The CRCs only run when a map is uploaded.
uint8_t crc8(const uint8_t *p, uint16_t n, uint8_t crc) {
  while (n--) {
    crc ^= *p++;
    for (uint8_t k = 8; k; k--) {
      const uint8_t top = crc;  // the bit shifted out, tested in 8 bits
      crc = (uint8_t)(crc << 1);
      if (top & 0x80) crc ^= 0x07;
    }
  }
  return crc;
}

uint32_t crc32_update(uint32_t crc, const uint8_t *p, uint16_t n) {
  crc = ~crc;
  while (n--) {
    crc ^= *p++;
    for (uint8_t k = 8; k; k--) {
      const uint8_t low = (uint8_t)crc;
      crc >>= 1;
      if (low & 1) crc ^= 0xEDB88320UL;
    }
  }
  return ~crc;
}

// ---- error texts: the Python codes, NUL-separated in one flash string ---------
static const char error_names[] BK_FLASH =
    "ok\0truncated\0magic\0version\0flags\0header_value\0header_crc\0record_crc\0varint\0count_zero\0"
    "count_max\0length\0coord\0z_order\0too_large\0no_header\0unknown";

const char *map_error_text(MapError e) {
  uint8_t i = (uint8_t)-(int16_t)e;  // codes above 0 wrap to large values
  if (i > (uint8_t)-MAP_ERR_NO_HEADER) i = (uint8_t)(1 - MAP_ERR_NO_HEADER);  // "unknown"
  const char *s = error_names;
  while (i--)
    while (BK_RD8(s++)) {
    }
  return s;
}

uint8_t map_error_copy(MapError e, char *buf, uint8_t size) {
  if (!size) return 0;
  const char *s = map_error_text(e);
  uint8_t n = 0;
  char c;
  while (n + 1 < size && (c = (char)BK_RD8(s + n)) != 0) buf[n++] = c;
  buf[n] = 0;
  return n;
}

// ---- varints ----------------------------------------------------------------------
// A varint at p: its value | its length << 24 (length 0: the data ends inside
// it; 0xFF: over-long or not minimal). One return register set instead of an
// out-parameter in RAM, and unrolled: deltas are mostly one byte, and a loop
// would need 32-bit variable shifts (slow on AVR) for the rest.
static uint32_t vread(const uint8_t *p, uint16_t avail) {
  if (!avail) return 0;
  const uint8_t b0 = p[0];
  if (!(b0 & 0x80)) return b0 | 1UL << 24;
  if (avail < 2) return 0;
  const uint8_t b1 = p[1];
  const uint16_t lo = (uint16_t)((b0 & 0x7F) | (uint16_t)(b1 & 0x7F) << 7);
  if (!(b1 & 0x80)) return b1 ? lo | 2UL << 24 : 0xFFUL << 24;  // a zero top group: not minimal
  if (avail < 3) return 0;
  const uint8_t b2 = p[2];
  if ((b2 & 0x80) || !b2) return 0xFFUL << 24;  // a fourth byte, or not minimal
  return lo | (uint32_t)b2 << 14 | 3UL << 24;
}

int8_t varint_read(const uint8_t *p, uint16_t avail, uint32_t &out) {
  const uint32_t v = vread(p, avail);
  const int8_t r = (int8_t)(v >> 24);
  if (r > 0) out = v & 0xFFFFFFUL;
  return r;
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
// present, CRC (by scan), body contents and length, then z order (by scan).
struct RecordHead {
  uint16_t z;
  uint8_t n;
  uint16_t body;  // offset of the body from the record start
  uint16_t size;  // whole record including the CRC byte
};

static MapError read_head(const uint8_t *p, uint16_t avail, RecordHead &h) {
  if (avail < 2) return MAP_ERR_TRUNCATED;
  h.z = (uint16_t)(p[0] | ((uint16_t)p[1] << 8));
  uint16_t off = 2;
  uint32_t v;
  if (avail >= 4 && !((p[2] | p[3]) & 0x80) && p[2] && p[2] <= BK_LAYER_POINTS_MAX) {
    // One-byte n and len, a valid n: the usual record, read without calls
    // (find_layer walks the heads).
    h.n = p[2];
    v = p[3];
    off = 4;
  } else {
    for (bool len = false;; len = true) {  // n, then len
      v = vread(p + off, (uint16_t)(avail - off));
      const int8_t r = (int8_t)(v >> 24);
      if (r <= 0) return r ? MAP_ERR_VARINT : MAP_ERR_TRUNCATED;
      off = (uint16_t)(off + r);
      v &= 0xFFFFFFUL;
      if (len) break;
      if (v == 0) return MAP_ERR_COUNT_ZERO;
      if (v > BK_LAYER_POINTS_MAX) return MAP_ERR_COUNT_MAX;
      h.n = (uint8_t)v;
    }
  }
  if (v >= (uint32_t)(avail - off)) return MAP_ERR_TRUNCATED;  // body + CRC byte
  h.body = off;
  h.size = (uint16_t)(off + v + 1);
  return MAP_OK;
}

// Parses the body of a record whose head is h; fills out when given. This is
// the decode at every layer change too, so the common one-byte delta takes a
// short 8/16-bit path.
static MapError read_body(const uint8_t *p, const RecordHead &h, bool weights, MapLayer *out) {
  const uint8_t *b = p + h.body;
  const uint8_t *const end = p + h.size - 1;  // the CRC byte
  // x0 y0 x1 y1 ...: one varint path for both axes. After each read, d holds
  // the coordinate just read and c the other one; a step that leaves int16
  // is noted and reported once the point's y has been read (the check order).
  int16_t c = 0, d = 0;
  bool off_range = false;
  MapPoint *pt = out ? out->pts : nullptr;
  for (uint16_t k = (uint16_t)(2u * h.n); k--;) {  // odd k: an x, even: a y
    const int16_t t = d;
    if (b < end && !(*b & 0x80)) {  // one byte, -64..63
      const int8_t dl = (int8_t)((*b >> 1) ^ -(*b & 1));
      b++;
      d = (int16_t)(uint16_t)((uint16_t)c + (uint16_t)dl);
      off_range |= (int16_t)((d ^ c) & (d ^ dl)) < 0;  // the sign flipped away from both
    } else {
      const uint32_t v = vread(b, (uint16_t)(end - b));
      const int8_t r = (int8_t)(v >> 24);
      if (r <= 0) return r ? MAP_ERR_VARINT : MAP_ERR_LENGTH;  // 0: body ends before the points do
      b += r;
      const int32_t s = c + zigzag_decode(v & 0xFFFFFFUL);
      d = (int16_t)s;
      off_range |= s != d;
    }
    c = t;
    if (k & 1) continue;
    if (off_range) return MAP_ERR_COORD;
    if (pt) {
      pt->x = c;
      pt->y = d;
      pt->w = MAP_WEIGHT_FULL;
      pt++;
    }
  }
  if (weights) {  // n bytes, then nothing
    if (end - b != h.n) return MAP_ERR_LENGTH;
    if (out)
      for (MapPoint *q = out->pts; b < end; q++) q->w = *b++;
  } else if (b != end) {
    return MAP_ERR_LENGTH;  // bytes after the last field
  }
  if (out) {
    out->z_cmm = h.z;
    out->count = h.n;
  }
  return MAP_OK;
}

uint16_t map_decode_record(const uint8_t *p, uint16_t avail, bool weights, MapLayer &out) {
  RecordHead h;
  if (read_head(p, avail, h) != MAP_OK || read_body(p, h, weights, &out) != MAP_OK) return 0;
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
  static_assert(sizeof(MapInfo) == 4, "MapInfo mirrors header bytes 3..6");
  memcpy(&info, p + 3, sizeof info);  // version, flags, quantum, layer height
  return MAP_OK;
}

// Validates the records in p[0, len): each must have z above z, which ends as
// the last record's z. On error, at is the failing record's offset.
static MapError scan(const uint8_t *p, uint16_t len, bool weights, int32_t &z, uint16_t &at) {
  for (at = 0; at < len;) {
    RecordHead h;
    MapError e = read_head(p + at, (uint16_t)(len - at), h);
    if (e == MAP_OK && crc8(p + at, (uint16_t)(h.size - 1)) != p[at + h.size - 1]) e = MAP_ERR_RECORD_CRC;
    if (e == MAP_OK) e = read_body(p + at, h, weights, 0);
    if (e == MAP_OK && (int32_t)h.z <= z) e = MAP_ERR_Z_ORDER;
    if (e != MAP_OK) return e;
    z = h.z;
    at = (uint16_t)(at + h.size);
  }
  return MAP_OK;
}

// ---- store ------------------------------------------------------------------------------
void MapStore::clear() {
  used_ = stage_size_ = error_offset_ = 0;
  z_floor_ = -1;
  memset(&info_, 0, sizeof info_);
}

MapError MapStore::load(const uint8_t *data, uint16_t len) {
  if (len < MAP_HEADER_BYTES) {
    error_offset_ = 0;
    return MAP_ERR_TRUNCATED;
  }
  return put(data, data + MAP_HEADER_BYTES, (uint16_t)(len - MAP_HEADER_BYTES));
}

// load_parts (header given) and append (header 0) in one: check everything,
// then copy; records may lie in the arena (the staging area), hence memmove.
MapError MapStore::put(const uint8_t *header, const uint8_t *records, uint16_t len) {
  error_offset_ = 0;
  if (!header && !loaded()) return MAP_ERR_NO_HEADER;
  const uint16_t at = header ? 0 : used_;
  if (len > BK_MAP_ARENA_BYTES - at) return MAP_ERR_TOO_LARGE;
  MapInfo info = info_;
  int32_t z = header ? -1 : z_floor_;
  MapError e = header ? map_parse_header(header, MAP_HEADER_BYTES, info) : MAP_OK;
  if (e != MAP_OK) return e;
  uint16_t bad;
  e = scan(records, len, info.flags & MAP_FLAG_WEIGHTS, z, bad);
  if (e != MAP_OK) {
    error_offset_ = (uint16_t)(bad + (header ? MAP_HEADER_BYTES : 0));
    return e;
  }
  memmove(arena_ + at, records, len);
  used_ = (uint16_t)(at + len);
  info_ = info;
  z_floor_ = z;
  stage_size_ = 0;
  return MAP_OK;
}

// The record walks below meet only validated records (checked on entry,
// moved whole by release_below); read_head's checks stop them anyway.
// The head of the record at off in the store, if there is one there.
static bool head_at(const MapStore &m, uint16_t off, RecordHead &h) {
  return off < m.bytes_used() && read_head(m.records() + off, (uint16_t)(m.bytes_used() - off), h) == MAP_OK;
}

uint16_t MapStore::counts(uint16_t &points) const {
  uint16_t layers = 0;
  points = 0;
  RecordHead h;
  for (uint16_t off = 0; head_at(*this, off, h); off = (uint16_t)(off + h.size)) {
    layers++;
    points = (uint16_t)(points + h.n);
  }
  return layers;
}

// One walk for the three layer questions: at = offset of the first record with
// z >= z_cmm (used_ if none), below = offset of the one before it (used_ if
// none). Records are in increasing z, so the walk stops there.
void MapStore::around(int32_t z_cmm, uint16_t &below, uint16_t &at) const {
  below = used_;
  RecordHead h;
  for (at = 0; head_at(*this, at, h) && (int32_t)h.z < z_cmm; at = (uint16_t)(at + h.size)) below = at;
}

bool MapStore::find_layer(int32_t z_cmm, MapLayer &out) const {
  uint16_t lo, hi;
  around(z_cmm, lo, hi);
  // The nearer of the two records around z_cmm; the lower one on a tie.
  const int32_t d_lo = lo < used_ ? z_cmm - z_at(lo) : INT32_MAX;
  const int32_t d_hi = hi < used_ ? z_at(hi) - z_cmm : INT32_MAX;
  const uint16_t best = d_lo <= d_hi ? lo : hi;
  const int32_t d = d_lo <= d_hi ? d_lo : d_hi;
  return d != INT32_MAX && 2 * d <= info_.layer_height_cmm &&
         map_decode_record(arena_ + best, (uint16_t)(used_ - best), info_.flags & MAP_FLAG_WEIGHTS, out);
}

void MapStore::neighbors(int32_t z_cmm, int32_t &below, int32_t &above) const {
  uint16_t lo, hi;
  around(z_cmm, lo, hi);
  below = lo < used_ ? (int32_t)z_at(lo) : -1;
  RecordHead h;
  if (head_at(*this, hi, h) && h.z == z_cmm) hi = (uint16_t)(hi + h.size);  // above is strictly above
  above = hi < used_ ? (int32_t)z_at(hi) : INT32_MAX;
}

void MapStore::release_below(int32_t z_cmm) {
  uint16_t lo, off;
  around(z_cmm, lo, off);
  if (!off) return;
  // Staged upload bytes sit right after the records and move with them.
  memmove(arena_, arena_ + off, (uint16_t)(used_ - off + stage_size_));
  used_ = (uint16_t)(used_ - off);  // z_floor_ keeps the append order
}

MapError MapStore::stage_open(uint16_t size) {
  stage_size_ = 0;
  if (size > free_bytes()) return MAP_ERR_TOO_LARGE;
  stage_size_ = size;
  return MAP_OK;
}

}  // namespace bk
