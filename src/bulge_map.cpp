// Compact bulge map v1 codec and store. See bulge_map.h and docs/map-format.md.
#include "bulge_map.h"

#include <string.h>

#ifdef __AVR__
#include <avr/pgmspace.h>
#define BKM_FLASH PROGMEM
#define BKM_RD8(p) pgm_read_byte(p)
#define BKM_RD32(p) pgm_read_dword(p)
#define BKM_RDPTR(p) ((const char *)pgm_read_word(p))
#define BKM_STR(s) PSTR(s)
#else
#define BKM_FLASH
#define BKM_RD8(p) (*(p))
#define BKM_RD32(p) (*(p))
#define BKM_RDPTR(p) (*(p))
#define BKM_STR(s) (s)
#endif

namespace bk {

// Byte-wise tables: about 20 AVR cycles a byte instead of ~80 bit by bit; they
// cost 1.25 KiB of flash and no RAM.
// CRC-8 poly 0x07: crc8_table[i] is the CRC of the single byte i.
static const uint8_t crc8_table[256] BKM_FLASH = {
    0x00, 0x07, 0x0E, 0x09, 0x1C, 0x1B, 0x12, 0x15, 0x38, 0x3F, 0x36, 0x31, 0x24, 0x23, 0x2A, 0x2D,
    0x70, 0x77, 0x7E, 0x79, 0x6C, 0x6B, 0x62, 0x65, 0x48, 0x4F, 0x46, 0x41, 0x54, 0x53, 0x5A, 0x5D,
    0xE0, 0xE7, 0xEE, 0xE9, 0xFC, 0xFB, 0xF2, 0xF5, 0xD8, 0xDF, 0xD6, 0xD1, 0xC4, 0xC3, 0xCA, 0xCD,
    0x90, 0x97, 0x9E, 0x99, 0x8C, 0x8B, 0x82, 0x85, 0xA8, 0xAF, 0xA6, 0xA1, 0xB4, 0xB3, 0xBA, 0xBD,
    0xC7, 0xC0, 0xC9, 0xCE, 0xDB, 0xDC, 0xD5, 0xD2, 0xFF, 0xF8, 0xF1, 0xF6, 0xE3, 0xE4, 0xED, 0xEA,
    0xB7, 0xB0, 0xB9, 0xBE, 0xAB, 0xAC, 0xA5, 0xA2, 0x8F, 0x88, 0x81, 0x86, 0x93, 0x94, 0x9D, 0x9A,
    0x27, 0x20, 0x29, 0x2E, 0x3B, 0x3C, 0x35, 0x32, 0x1F, 0x18, 0x11, 0x16, 0x03, 0x04, 0x0D, 0x0A,
    0x57, 0x50, 0x59, 0x5E, 0x4B, 0x4C, 0x45, 0x42, 0x6F, 0x68, 0x61, 0x66, 0x73, 0x74, 0x7D, 0x7A,
    0x89, 0x8E, 0x87, 0x80, 0x95, 0x92, 0x9B, 0x9C, 0xB1, 0xB6, 0xBF, 0xB8, 0xAD, 0xAA, 0xA3, 0xA4,
    0xF9, 0xFE, 0xF7, 0xF0, 0xE5, 0xE2, 0xEB, 0xEC, 0xC1, 0xC6, 0xCF, 0xC8, 0xDD, 0xDA, 0xD3, 0xD4,
    0x69, 0x6E, 0x67, 0x60, 0x75, 0x72, 0x7B, 0x7C, 0x51, 0x56, 0x5F, 0x58, 0x4D, 0x4A, 0x43, 0x44,
    0x19, 0x1E, 0x17, 0x10, 0x05, 0x02, 0x0B, 0x0C, 0x21, 0x26, 0x2F, 0x28, 0x3D, 0x3A, 0x33, 0x34,
    0x4E, 0x49, 0x40, 0x47, 0x52, 0x55, 0x5C, 0x5B, 0x76, 0x71, 0x78, 0x7F, 0x6A, 0x6D, 0x64, 0x63,
    0x3E, 0x39, 0x30, 0x37, 0x22, 0x25, 0x2C, 0x2B, 0x06, 0x01, 0x08, 0x0F, 0x1A, 0x1D, 0x14, 0x13,
    0xAE, 0xA9, 0xA0, 0xA7, 0xB2, 0xB5, 0xBC, 0xBB, 0x96, 0x91, 0x98, 0x9F, 0x8A, 0x8D, 0x84, 0x83,
    0xDE, 0xD9, 0xD0, 0xD7, 0xC2, 0xC5, 0xCC, 0xCB, 0xE6, 0xE1, 0xE8, 0xEF, 0xFA, 0xFD, 0xF4, 0xF3,
};

// CRC-32 IEEE, reflected poly 0xEDB88320, one entry per byte value.
static const uint32_t crc32_table[256] BKM_FLASH = {
    0x00000000UL, 0x77073096UL, 0xEE0E612CUL, 0x990951BAUL, 0x076DC419UL, 0x706AF48FUL,
    0xE963A535UL, 0x9E6495A3UL, 0x0EDB8832UL, 0x79DCB8A4UL, 0xE0D5E91EUL, 0x97D2D988UL,
    0x09B64C2BUL, 0x7EB17CBDUL, 0xE7B82D07UL, 0x90BF1D91UL, 0x1DB71064UL, 0x6AB020F2UL,
    0xF3B97148UL, 0x84BE41DEUL, 0x1ADAD47DUL, 0x6DDDE4EBUL, 0xF4D4B551UL, 0x83D385C7UL,
    0x136C9856UL, 0x646BA8C0UL, 0xFD62F97AUL, 0x8A65C9ECUL, 0x14015C4FUL, 0x63066CD9UL,
    0xFA0F3D63UL, 0x8D080DF5UL, 0x3B6E20C8UL, 0x4C69105EUL, 0xD56041E4UL, 0xA2677172UL,
    0x3C03E4D1UL, 0x4B04D447UL, 0xD20D85FDUL, 0xA50AB56BUL, 0x35B5A8FAUL, 0x42B2986CUL,
    0xDBBBC9D6UL, 0xACBCF940UL, 0x32D86CE3UL, 0x45DF5C75UL, 0xDCD60DCFUL, 0xABD13D59UL,
    0x26D930ACUL, 0x51DE003AUL, 0xC8D75180UL, 0xBFD06116UL, 0x21B4F4B5UL, 0x56B3C423UL,
    0xCFBA9599UL, 0xB8BDA50FUL, 0x2802B89EUL, 0x5F058808UL, 0xC60CD9B2UL, 0xB10BE924UL,
    0x2F6F7C87UL, 0x58684C11UL, 0xC1611DABUL, 0xB6662D3DUL, 0x76DC4190UL, 0x01DB7106UL,
    0x98D220BCUL, 0xEFD5102AUL, 0x71B18589UL, 0x06B6B51FUL, 0x9FBFE4A5UL, 0xE8B8D433UL,
    0x7807C9A2UL, 0x0F00F934UL, 0x9609A88EUL, 0xE10E9818UL, 0x7F6A0DBBUL, 0x086D3D2DUL,
    0x91646C97UL, 0xE6635C01UL, 0x6B6B51F4UL, 0x1C6C6162UL, 0x856530D8UL, 0xF262004EUL,
    0x6C0695EDUL, 0x1B01A57BUL, 0x8208F4C1UL, 0xF50FC457UL, 0x65B0D9C6UL, 0x12B7E950UL,
    0x8BBEB8EAUL, 0xFCB9887CUL, 0x62DD1DDFUL, 0x15DA2D49UL, 0x8CD37CF3UL, 0xFBD44C65UL,
    0x4DB26158UL, 0x3AB551CEUL, 0xA3BC0074UL, 0xD4BB30E2UL, 0x4ADFA541UL, 0x3DD895D7UL,
    0xA4D1C46DUL, 0xD3D6F4FBUL, 0x4369E96AUL, 0x346ED9FCUL, 0xAD678846UL, 0xDA60B8D0UL,
    0x44042D73UL, 0x33031DE5UL, 0xAA0A4C5FUL, 0xDD0D7CC9UL, 0x5005713CUL, 0x270241AAUL,
    0xBE0B1010UL, 0xC90C2086UL, 0x5768B525UL, 0x206F85B3UL, 0xB966D409UL, 0xCE61E49FUL,
    0x5EDEF90EUL, 0x29D9C998UL, 0xB0D09822UL, 0xC7D7A8B4UL, 0x59B33D17UL, 0x2EB40D81UL,
    0xB7BD5C3BUL, 0xC0BA6CADUL, 0xEDB88320UL, 0x9ABFB3B6UL, 0x03B6E20CUL, 0x74B1D29AUL,
    0xEAD54739UL, 0x9DD277AFUL, 0x04DB2615UL, 0x73DC1683UL, 0xE3630B12UL, 0x94643B84UL,
    0x0D6D6A3EUL, 0x7A6A5AA8UL, 0xE40ECF0BUL, 0x9309FF9DUL, 0x0A00AE27UL, 0x7D079EB1UL,
    0xF00F9344UL, 0x8708A3D2UL, 0x1E01F268UL, 0x6906C2FEUL, 0xF762575DUL, 0x806567CBUL,
    0x196C3671UL, 0x6E6B06E7UL, 0xFED41B76UL, 0x89D32BE0UL, 0x10DA7A5AUL, 0x67DD4ACCUL,
    0xF9B9DF6FUL, 0x8EBEEFF9UL, 0x17B7BE43UL, 0x60B08ED5UL, 0xD6D6A3E8UL, 0xA1D1937EUL,
    0x38D8C2C4UL, 0x4FDFF252UL, 0xD1BB67F1UL, 0xA6BC5767UL, 0x3FB506DDUL, 0x48B2364BUL,
    0xD80D2BDAUL, 0xAF0A1B4CUL, 0x36034AF6UL, 0x41047A60UL, 0xDF60EFC3UL, 0xA867DF55UL,
    0x316E8EEFUL, 0x4669BE79UL, 0xCB61B38CUL, 0xBC66831AUL, 0x256FD2A0UL, 0x5268E236UL,
    0xCC0C7795UL, 0xBB0B4703UL, 0x220216B9UL, 0x5505262FUL, 0xC5BA3BBEUL, 0xB2BD0B28UL,
    0x2BB45A92UL, 0x5CB36A04UL, 0xC2D7FFA7UL, 0xB5D0CF31UL, 0x2CD99E8BUL, 0x5BDEAE1DUL,
    0x9B64C2B0UL, 0xEC63F226UL, 0x756AA39CUL, 0x026D930AUL, 0x9C0906A9UL, 0xEB0E363FUL,
    0x72076785UL, 0x05005713UL, 0x95BF4A82UL, 0xE2B87A14UL, 0x7BB12BAEUL, 0x0CB61B38UL,
    0x92D28E9BUL, 0xE5D5BE0DUL, 0x7CDCEFB7UL, 0x0BDBDF21UL, 0x86D3D2D4UL, 0xF1D4E242UL,
    0x68DDB3F8UL, 0x1FDA836EUL, 0x81BE16CDUL, 0xF6B9265BUL, 0x6FB077E1UL, 0x18B74777UL,
    0x88085AE6UL, 0xFF0F6A70UL, 0x66063BCAUL, 0x11010B5CUL, 0x8F659EFFUL, 0xF862AE69UL,
    0x616BFFD3UL, 0x166CCF45UL, 0xA00AE278UL, 0xD70DD2EEUL, 0x4E048354UL, 0x3903B3C2UL,
    0xA7672661UL, 0xD06016F7UL, 0x4969474DUL, 0x3E6E77DBUL, 0xAED16A4AUL, 0xD9D65ADCUL,
    0x40DF0B66UL, 0x37D83BF0UL, 0xA9BCAE53UL, 0xDEBB9EC5UL, 0x47B2CF7FUL, 0x30B5FFE9UL,
    0xBDBDF21CUL, 0xCABAC28AUL, 0x53B39330UL, 0x24B4A3A6UL, 0xBAD03605UL, 0xCDD70693UL,
    0x54DE5729UL, 0x23D967BFUL, 0xB3667A2EUL, 0xC4614AB8UL, 0x5D681B02UL, 0x2A6F2B94UL,
    0xB40BBE37UL, 0xC30C8EA1UL, 0x5A05DF1BUL, 0x2D02EF8DUL,
};

uint8_t crc8(const uint8_t *p, uint16_t n, uint8_t crc) {
  while (n--) crc = BKM_RD8(&crc8_table[crc ^ *p++]);
  return crc;
}

uint32_t crc32_update(uint32_t crc, const uint8_t *p, uint16_t n) {
  crc = ~crc;
  while (n--) crc = BKM_RD32(&crc32_table[(uint8_t)crc ^ *p++]) ^ (crc >> 8);
  return ~crc;
}

// ---- error texts (flash on AVR) -------------------------------------------------
static const char et_ok[] BKM_FLASH = "ok";
static const char et_truncated[] BKM_FLASH = "truncated";
static const char et_magic[] BKM_FLASH = "bad magic (not a BKM map)";
static const char et_version[] BKM_FLASH = "unsupported version";
static const char et_flags[] BKM_FLASH = "unknown flag bits";
static const char et_hvalue[] BKM_FLASH = "quantum or layer height is 0";
static const char et_hcrc[] BKM_FLASH = "header CRC mismatch";
static const char et_rcrc[] BKM_FLASH = "record CRC mismatch";
static const char et_varint[] BKM_FLASH = "over-long varint";
static const char et_nzero[] BKM_FLASH = "layer with 0 points";
static const char et_nmax[] BKM_FLASH = "too many points in a layer";
static const char et_length[] BKM_FLASH = "record length mismatch";
static const char et_coord[] BKM_FLASH = "coordinate out of int16 range";
static const char et_zorder[] BKM_FLASH = "z not increasing";
static const char et_large[] BKM_FLASH = "map too large";
static const char et_noheader[] BKM_FLASH = "no map loaded to append to";
static const char et_unknown[] BKM_FLASH = "unknown error";
static const char *const error_texts[] BKM_FLASH = {
    et_ok,    et_truncated, et_magic, et_version, et_flags, et_hvalue, et_hcrc, et_rcrc,
    et_varint, et_nzero,    et_nmax,  et_length,  et_coord, et_zorder, et_large, et_noheader,
};

const char *map_error_text(MapError e) {
  int8_t i = (int8_t)-e;
  if (i < 0 || i >= (int8_t)(sizeof(error_texts) / sizeof(error_texts[0]))) return et_unknown;
  return BKM_RDPTR(&error_texts[i]);
}

uint8_t map_error_copy(MapError e, char *buf, uint8_t size) {
  if (!size) return 0;
  const char *s = map_error_text(e);
  uint8_t n = 0;
  char c;
  while (n + 1 < size && (c = (char)BKM_RD8((const uint8_t *)s + n)) != 0) buf[n++] = c;
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
