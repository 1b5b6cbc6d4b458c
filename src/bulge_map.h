// Compact bulge map v1: checksums, varints, validation and the in-RAM store.
//
// The host sends the bulge points of every layer as a small binary image (see
// docs/reference/map-format.md). The firmware keeps that image compact in a fixed arena
// and decodes one layer record into a MapLayer only when printing reaches it,
// so a few hundred points cost a few bytes each instead of 5 bytes of struct.
// Records are validated in full (CRC, varints, ranges, z order) before they are
// accepted, so decoding at print time cannot meet malformed data.
//
// No heap, no STL; builds with avr-gcc 5.4 (gnu++11).
#ifndef BK_BULGE_MAP_H
#define BK_BULGE_MAP_H

#include <stdint.h>

#include "bulgekit_config.h"

#if BK_LAYER_POINTS_MAX > 255 || BK_LAYER_POINTS_MAX < 1
#error "BK_LAYER_POINTS_MAX must be 1..255 (MapLayer::count is a uint8_t)"
#endif
#if BK_MAP_ARENA_BYTES > 65000
#error "BK_MAP_ARENA_BYTES must fit the uint16_t offsets used by MapStore"
#endif
// A record of n points is at most 7 n + 7 bytes (z, n, len, 3-byte deltas,
// weights, CRC); streaming needs the layer in print and the next one.
#if BK_MAP_ARENA_BYTES < 2 * (7 * BK_LAYER_POINTS_MAX + 7)
#error "BK_MAP_ARENA_BYTES must hold two full layers: 2 * (7 * BK_LAYER_POINTS_MAX + 7) bytes"
#endif

namespace bk {

static const uint8_t MAP_HEADER_BYTES = 8;
static const uint8_t MAP_VERSION = 1;
static const uint8_t MAP_FLAG_WEIGHTS = 0x01;
static const uint8_t MAP_VARINT_MAX_BYTES = 3;  // values < 2^21
static const uint8_t MAP_WEIGHT_FULL = 255;      // "no weights" maps report this

struct MapPoint {
  int16_t x, y;  // quanta of MapInfo::quantum_um
  uint8_t w;     // dwell weight 0..255; 255 when the map has no weights
};

struct MapLayer {
  uint16_t z_cmm;  // 0.01 mm
  uint8_t count;
  MapPoint pts[BK_LAYER_POINTS_MAX];
};

struct MapInfo {
  uint8_t version;           // 0 while no map is loaded
  uint8_t flags;             // MAP_FLAG_WEIGHTS
  uint8_t quantum_um;        // XY quantum
  uint8_t layer_height_cmm;  // a layer matches z within half of this
};

// Negative codes; the names match the Python codes in host/bulgekit/mapformat.py
// (MAP_ERR_RECORD_CRC <-> "record_crc") so both sides classify a vector alike.
enum MapError : int8_t {
  MAP_OK = 0,
  MAP_ERR_TRUNCATED = -1,     // data ends inside the header or a record
  MAP_ERR_MAGIC = -2,         // not 'BKM'
  MAP_ERR_VERSION = -3,       // version other than 1
  MAP_ERR_FLAGS = -4,         // unknown flag bits set
  MAP_ERR_HEADER_VALUE = -5,  // quantum or layer height of 0
  MAP_ERR_HEADER_CRC = -6,
  MAP_ERR_RECORD_CRC = -7,
  MAP_ERR_VARINT = -8,        // longer than 3 bytes, or not minimally encoded
  MAP_ERR_COUNT_ZERO = -9,    // n == 0
  MAP_ERR_COUNT_MAX = -10,    // n > BK_LAYER_POINTS_MAX
  MAP_ERR_LENGTH = -11,       // len differs from the body the points need
  MAP_ERR_COORD = -12,        // a coordinate leaves int16
  MAP_ERR_Z_ORDER = -13,      // z not strictly increasing (also across appends)
  MAP_ERR_TOO_LARGE = -14,    // does not fit the arena (or its free space)
  MAP_ERR_NO_HEADER = -15,    // records appended while no map is loaded
};

// The error's name, the Python code of the same error ("record_crc"; "ok",
// "no_header", "unknown" for codes outside the list). On AVR the text lives in
// flash: print it with a _P function, or copy it with map_error_copy(), which
// works on both.
const char *map_error_text(MapError e);
// Copies the text into buf (always NUL-terminated); returns its length.
uint8_t map_error_copy(MapError e, char *buf, uint8_t size);

// CRC-8: poly 0x07, init 0, no reflection, no xorout (the map header/records).
uint8_t crc8(const uint8_t *p, uint16_t n, uint8_t crc = 0);
// IEEE CRC-32 as zlib.crc32: crc32_update(0, ...) starts; chain by passing the
// previous result.
uint32_t crc32_update(uint32_t crc, const uint8_t *p, uint16_t n);

// Varint (unsigned LEB128, <= 3 bytes, minimal) and zigzag helpers.
// varint_read returns bytes consumed, 0 if truncated, or -1 if malformed.
int8_t varint_read(const uint8_t *p, uint16_t avail, uint32_t &out);
// Writes v (< 2^21) and returns bytes written (1..3), 0 if v is too large.
uint8_t varint_write(uint8_t *p, uint32_t v);
inline uint32_t zigzag_encode(int32_t v) { return ((uint32_t)v << 1) ^ (uint32_t)(v >> 31); }
inline int32_t zigzag_decode(uint32_t u) { return (int32_t)(u >> 1) ^ -(int32_t)(u & 1); }

// Checks an 8-byte header (magic, CRC, version, flags, values; in that order)
// and fills info. len < 8 is MAP_ERR_TRUNCATED.
MapError map_parse_header(const uint8_t *p, uint16_t len, MapInfo &info);

// The one record decoder: decodes the record at p into out with every check
// but the CRC (the store checks that on entry); returns the record's total
// size, or 0 on malformed data. find_layer uses it at each layer change.
uint16_t map_decode_record(const uint8_t *p, uint16_t avail, bool weights, MapLayer &out);

// The map in force, compact, in a fixed arena of BK_MAP_ARENA_BYTES (no heap).
// The arena holds the layer records; the 8-byte header is kept decoded in
// info(). The free space after the records doubles as the staging area for an
// M721 upload (see stage_open), so an upload costs no RAM of its own. Counts
// and the first z are read from the records when asked (status, tests), so the
// bookkeeping is 14 bytes.
class MapStore {
 public:
  MapStore() { clear(); }
  void clear();  // no map, no layers; closes any staging
  // Replace the map with a full validated image (header + records). On error
  // the map in force is unchanged. Success closes any staging (data may point
  // into the staging area itself).
  MapError load(const uint8_t *data, uint16_t len);
  // The same with the header apart from the records (M721 keeps the header
  // outside the arena so a full arena's worth of records can be staged).
  // error_offset() still counts from the header's first byte.
  MapError load_parts(const uint8_t *header, const uint8_t *records, uint16_t len) {
    return put(header, records, len);
  }
  // Add records after the last layer: validated, all-or-nothing, first z above
  // every z this map has held (released layers included). Success closes any
  // staging; data may point at the staging area.
  MapError append(const uint8_t *records, uint16_t len) { return put(0, records, len); }

  bool loaded() const { return info_.version != 0; }  // a header is in force
  bool empty() const { return used_ == 0; }           // no layer records
  const MapInfo &info() const { return info_; }
  uint16_t layer_count() const {
    uint16_t points;
    return counts(points);
  }
  uint16_t bytes_used() const { return used_; }  // record bytes in the arena
  uint16_t capacity() const { return BK_MAP_ARENA_BYTES; }
  uint16_t free_bytes() const { return (uint16_t)(BK_MAP_ARENA_BYTES - used_); }
  uint16_t point_count() const {
    uint16_t points;
    counts(points);
    return points;
  }
  // Layers in force, and their points, in one walk of the records.
  uint16_t counts(uint16_t &points) const;
  // 0 when empty. The last record is the one added last, with z_floor's z.
  uint16_t first_z() const { return used_ ? z_at(0) : 0; }
  uint16_t last_z() const { return used_ ? (uint16_t)z_floor_ : 0; }
  // Highest z the map has held (appends must exceed it); -1 for none.
  int32_t z_floor() const { return z_floor_; }

  // The layer whose z is within half a layer height of z_cmm (|dz|*2 <= h;
  // the nearer one if two, the lower one on a tie), decoded into out.
  bool find_layer(int32_t z_cmm, MapLayer &out) const;
  // z (cmm) of the records next to z_cmm: the highest below it (-1 if none)
  // and the lowest above it (INT32_MAX if none). The layer window uses them to
  // hand over to a nearer layer when layers are closer than a layer height.
  void neighbors(int32_t z_cmm, int32_t &below, int32_t &above) const;
  // Release every layer with z < z_cmm (consumed while printing): the rest,
  // and any staged upload bytes, move down so appends fit.
  void release_below(int32_t z_cmm);

  // After load/append fails: offset of the failing record in the data given
  // (0 for header errors), to name the spot in an error message.
  uint16_t error_offset() const { return error_offset_; }

  // Raw access for tests and tools: the record bytes in force.
  const uint8_t *records() const { return arena_; }

  // ---- upload staging (used by MapUpload) ----
  // Reserve size bytes of the free space right after the records. Replaces any
  // open staging; fails with MAP_ERR_TOO_LARGE (and none open) if they do not fit.
  MapError stage_open(uint16_t size);
  uint8_t *stage_data() { return arena_ + used_; }
  const uint8_t *stage_data() const { return arena_ + used_; }
  uint16_t stage_size() const { return stage_size_; }  // 0 when none open
  void stage_close() { stage_size_ = 0; }

 private:
  MapError put(const uint8_t *header, const uint8_t *records, uint16_t len);  // header 0: append
  void around(int32_t z_cmm, uint16_t &below, uint16_t &at) const;
  uint16_t z_at(uint16_t off) const { return (uint16_t)(arena_[off] | (uint16_t)arena_[off + 1] << 8); }

  // The small fields first: AVR reaches them with a displacement from the
  // object (at most 63 bytes), not with an address sum past the arena.
  uint16_t used_;
  int32_t z_floor_;
  uint16_t stage_size_;
  uint16_t error_offset_;
  MapInfo info_;
  uint8_t arena_[BK_MAP_ARENA_BYTES];
};

}  // namespace bk

#endif  // BK_BULGE_MAP_H
