// M721 upload: the host builder's transcripts (test/vectors/*.m721) played
// through GcodeArgs + MapUpload, and every error path of begin/chunk/commit.
#include <string.h>

#include "bktest.h"
#include "bulge_map.h"
#include "gcode_args.h"
#include "map_upload.h"
#include "../vectors/vectors.h"

#ifdef __AVR__
#define FLASH_COPY(dst, src, n) memcpy_P((dst), (src), (n))
#define FLASH_CHAR(p) ((char)pgm_read_byte(p))
#define P_EQ(r, lit) (strcmp_P((r), PSTR(lit)) == 0)
#define P_HAS(r, lit) (strstr_P((r), PSTR(lit)) != 0)
#else
#define FLASH_COPY(dst, src, n) memcpy((dst), (src), (n))
#define FLASH_CHAR(p) (*(p))
#define P_EQ(r, lit) (strcmp((r), (lit)) == 0)
#define P_HAS(r, lit) (strstr((r), (lit)) != 0)
#endif

using namespace bk;

static MapStore store;
static MapUpload up(store);
static GcodeArgs args;
static char line[100];
static char reply[BK_M721_REPLY_BYTES];
static uint8_t buf[256];
static MapLayer layer;

void setUp(void) {
  up.abort();
  store.clear();
}

static void show_reply(void) {
  TEST_PRINT("  reply: ");
  bkt_puts(reply);
  bkt_putc('\n');
}
// The reply must be exactly / contain / start with a literal (flash on AVR).
#define EXPECT_REPLY(lit)                               \
  do {                                                  \
    if (!P_EQ(reply, lit)) {                            \
      show_reply();                                     \
      TEST_FAIL_MESSAGE("reply is not: " lit);          \
    }                                                   \
  } while (0)
#define EXPECT_IN_REPLY(lit)                            \
  do {                                                  \
    if (!P_HAS(reply, lit)) {                           \
      show_reply();                                     \
      TEST_FAIL_MESSAGE("reply lacks: " lit);           \
    }                                                   \
  } while (0)

static UploadStatus send_ram(void) {
  TEST_ASSERT_TRUE(args.parse(line));
  return up.handle(args, reply, sizeof reply);
}
// Sends a literal command line.
#ifdef __AVR__
#define SEND(lit) (strcpy_P(line, PSTR(lit)), send_ram())
#else
#define SEND(lit) (strcpy(line, lit), send_ram())
#endif

// ---- line builders for payloads made at run time ----------------------------------------
static char *put_u(char *p, uint32_t v) {
  char t[10];
  uint8_t n = 0;
  do t[n++] = (char)('0' + v % 10), v /= 10;
  while (v);
  while (n) *p++ = t[--n];
  return p;
}
static char *put_s(char *p, const char *s) {
  while (*s) *p++ = *s++;
  return p;
}
static uint8_t b32_encode(const uint8_t *d, uint8_t n, char *out) {
  static const char abc[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZ234567";
  uint16_t acc = 0;
  uint8_t bits = 0, k = 0;
  for (uint8_t i = 0; i < n; i++) {
    acc = (uint16_t)((acc << 8) | d[i]);
    bits += 8;
    while (bits >= 5) {
      bits -= 5;
      out[k++] = abc[(acc >> bits) & 31];
    }
  }
  if (bits) out[k++] = abc[(acc << (5 - bits)) & 31];
  out[k] = 0;
  return k;
}
static UploadStatus send_begin(uint16_t size, uint32_t crc, bool append) {
  char *p = put_s(line, "M721 S");
  p = put_u(p, size);
  p = put_s(p, " C");
  p = put_u(p, crc);
  if (append) p = put_s(p, " A1");
  *p = 0;
  return send_ram();
}
static UploadStatus send_chunk(uint16_t off, const uint8_t *d, uint8_t n) {
  char *p = put_s(line, "M721 O");
  p = put_u(p, off);
  p = put_s(p, " D");
  b32_encode(d, n, p);
  return send_ram();
}
// Uploads data in 40-byte chunks and commits.
static UploadStatus upload(const uint8_t *d, uint16_t n, bool append) {
  if (send_begin(n, crc32_update(0, d, n), append) != UPLOAD_OK) return UPLOAD_ERROR;
  for (uint16_t off = 0; off < n; off += 40)
    if (send_chunk(off, d + off, (uint8_t)(n - off < 40 ? n - off : 40)) != UPLOAD_OK) return UPLOAD_ERROR;
  return SEND("M721 E");
}
static uint16_t fetch(const uint8_t *flash, uint16_t n) {
  FLASH_COPY(buf, flash, n);
  return n;
}
#define FETCH(v) fetch(v, sizeof(v))

// Plays a transcript from flash line by line; returns commits seen, or -1 at
// the first Error reply (printed).
static int16_t play(const char *script) {
  int16_t commits = 0;
  const char *s = script;
  for (;;) {
    uint8_t n = 0;
    char c;
    while ((c = FLASH_CHAR(s)) != 0 && c != '\n') {
      if (n < sizeof line - 1) line[n++] = c;
      s++;
    }
    line[n] = 0;
    if (c) s++;
    if (!n && !c) return commits;
    TEST_ASSERT_LESS_OR_EQUAL_INT(95, n);  // Marlin's buffer
    if (!strncmp(line, "; @release_below ", 17)) {
      int32_t z = 0;
      for (const char *p = line + 17; *p; p++) z = z * 10 + (*p - '0');
      store.release_below(z);
      continue;
    }
    if (line[0] == ';' || !n) continue;
    UploadStatus st = send_ram();
    if (st == UPLOAD_ERROR) {
      bkt_puts(line);
      bkt_putc('\n');
      show_reply();
      return -1;
    }
    if (st == UPLOAD_COMMITTED) commits++;
  }
}

// ---- transcripts -----------------------------------------------------------------------------
static void test_transcript_tiny(void) {
  TEST_ASSERT_EQUAL_INT(1, play(bkv_tiny_m721));
  EXPECT_REPLY("echo:BulgeMap layers:1 bytes:12/2048 points:3 z:0.60..0.60");
  uint16_t n = FETCH(bkv_tiny);
  TEST_ASSERT_EQUAL_UINT16(n - 8, store.bytes_used());
  TEST_ASSERT_EQUAL_MEMORY(buf + 8, store.records(), n - 8);
  TEST_ASSERT_TRUE(store.find_layer(60, layer));
  TEST_ASSERT_EQUAL_INT16(196, layer.pts[2].x);
  TEST_ASSERT_EQUAL_INT16(40, layer.pts[2].y);
}

static void test_transcript_head_then_append(void) {
  TEST_ASSERT_EQUAL_INT(2, play(bkv_text_cylinder_m721));
  TEST_ASSERT_EQUAL_UINT16(34, store.layer_count());
  TEST_ASSERT_EQUAL_UINT16(484, store.point_count());
  TEST_ASSERT_EQUAL_UINT16(sizeof bkv_text_cylinder - 8, store.bytes_used());
  // Records in force == text_cylinder.bkm after its header, compared in 200-byte pieces.
  for (uint16_t off = 0; off < store.bytes_used(); off += 200) {
    uint16_t n = store.bytes_used() - off < 200 ? store.bytes_used() - off : 200;
    FLASH_COPY(buf, bkv_text_cylinder + 8 + off, n);
    TEST_ASSERT_EQUAL_MEMORY(buf, store.records() + off, n);
  }
}

static void test_transcript_streams_a_map_larger_than_the_arena(void) {
  TEST_ASSERT_TRUE(sizeof bkv_text_tall > BK_MAP_ARENA_BYTES + 8);
  int16_t commits = play(bkv_text_tall_stream_m721);
  TEST_ASSERT_GREATER_OR_EQUAL_INT(3, commits);
  // What remains is the tail of text_tall.bkm, byte for byte.
  const uint16_t used = store.bytes_used();
  const uint16_t start = (uint16_t)(sizeof bkv_text_tall - used);
  for (uint16_t off = 0; off < used; off += 200) {
    uint16_t n = used - off < 200 ? used - off : 200;
    FLASH_COPY(buf, bkv_text_tall + start + off, n);
    TEST_ASSERT_EQUAL_MEMORY(buf, store.records() + off, n);
  }
  TEST_ASSERT_EQUAL_UINT16(2400, store.last_z());  // text_tall.json's last layer
  TEST_ASSERT_TRUE(store.first_z() > 300);  // early layers were released
}

// ---- begin/chunk/commit ------------------------------------------------------------------------
static void test_happy_path_replies(void) {
  const uint16_t n = FETCH(bkv_weights);
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_begin(n, bkv_weights_crc32, false));
  EXPECT_REPLY("echo:M721 receiving 39 bytes");
  TEST_ASSERT_TRUE(up.open());
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_chunk(0, buf, 40 > n ? n : 40));
  EXPECT_REPLY("");  // chunks are quiet
  TEST_ASSERT_EQUAL_UINT16(n, up.received());
  TEST_ASSERT_EQUAL_INT(UPLOAD_COMMITTED, SEND("M721 E"));
  EXPECT_REPLY("echo:BulgeMap layers:2 bytes:31/2048 points:5 z:0.20..0.50");
  TEST_ASSERT_FALSE(up.open());
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, SEND("M721"));
  EXPECT_REPLY("echo:BulgeMap layers:2 bytes:31/2048 points:5 z:0.20..0.50");
  TEST_ASSERT_EQUAL_INT(UPLOAD_CLEARED, SEND("M721 X"));
  EXPECT_REPLY("echo:BulgeMap cleared");
  TEST_ASSERT_FALSE(store.loaded());
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, SEND("M721"));
  EXPECT_REPLY("echo:BulgeMap layers:0 bytes:0/2048 points:0 z:-");
}

static void test_resent_chunk_is_harmless(void) {
  const uint16_t n = FETCH(bkv_full_layer);  // 208 bytes: 6 chunks
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_begin(n, bkv_full_layer_crc32, false));
  for (uint16_t off = 0; off < n; off += 40) {
    uint8_t k = (uint8_t)(n - off < 40 ? n - off : 40);
    TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_chunk(off, buf + off, k));
    TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_chunk(off, buf + off, k));  // resent
    if (off) TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_chunk(off - 40, buf + off - 40, 40));  // older one
    TEST_ASSERT_EQUAL_UINT16(off + k, up.received());
  }
  TEST_ASSERT_EQUAL_INT(UPLOAD_COMMITTED, SEND("M721 E"));
  TEST_ASSERT_EQUAL_UINT16(64, store.point_count());
  // Overlapping (unaligned) resends are fine too.
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_begin(n, bkv_full_layer_crc32, false));
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_chunk(0, buf, 40));
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_chunk(35, buf + 35, 40));
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_chunk(10, buf + 10, 20));
  TEST_ASSERT_EQUAL_UINT16(75, up.received());
}

static void test_gap_is_an_error(void) {
  const uint16_t n = FETCH(bkv_full_layer);
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_begin(n, bkv_full_layer_crc32, false));
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, send_chunk(40, buf + 40, 40));
  EXPECT_REPLY("Error:M721 O40 not in 0..0");  // a gap
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_chunk(0, buf, 40));
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, send_chunk(41, buf + 41, 5));
  EXPECT_REPLY("Error:M721 O41 not in 0..40");
  TEST_ASSERT_EQUAL_UINT16(40, up.received());
  TEST_ASSERT_TRUE(up.open());
  // Past the announced size.
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_chunk(40, buf + 40, 40));
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_chunk(80, buf + 80, 40));
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_chunk(120, buf + 120, 40));
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_chunk(160, buf + 160, 40));
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, send_chunk(200, buf + 200, 10));
  EXPECT_REPLY("Error:M721 O200+10 > S208");
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_chunk(200, buf + 200, 8));
  TEST_ASSERT_EQUAL_INT(UPLOAD_COMMITTED, SEND("M721 E"));
}

static void test_bad_base32(void) {
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_begin(20, 1, false));
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 O0 DMFRGG1DF"));
  EXPECT_REPLY("Error:M721 D bad base32 at char 5");
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 O0 DMFRG=="));  // no padding in M721
  EXPECT_REPLY("Error:M721 D bad base32 at char 4");
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 O0 DMFR"));  // 3 chars: no whole byte count
  EXPECT_REPLY("Error:M721 D bad base32 at char 3");
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 O0 DMB"));  // 'B' leaves a 1 in the unused bits
  EXPECT_REPLY("Error:M721 D bad base32 at char 1");
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 O0 D"));
  EXPECT_REPLY("Error:M721 D missing or bad");
  char *p = put_s(line, "M721 O0 D");
  for (uint8_t i = 0; i < 72; i++) *p++ = 'A';
  *p = 0;
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, send_ram());
  EXPECT_REPLY("Error:M721 D bad base32 at char 64");  // the first char too many
  line[9 + 64] = 0;  // 64 chars: accepted (40 zero bytes)
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, send_ram());
  EXPECT_REPLY("Error:M721 O0+40 > S20");
  TEST_ASSERT_EQUAL_UINT16(0, up.received());
  // Lower case decodes like upper case: "my" = 0x66.
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, SEND("M721 O0 dmy"));
  TEST_ASSERT_EQUAL_UINT16(1, up.received());
  uint8_t pos = 9;
  uint8_t one = 0;
  TEST_ASSERT_EQUAL_INT(1, base32_decode("my", 2, &one, pos));
  TEST_ASSERT_EQUAL_HEX8(0x66, one);
  uint8_t out[5];
  TEST_ASSERT_EQUAL_INT(5, base32_decode("MZXW6YTB", 8, out, pos));  // "fooba"
  TEST_ASSERT_EQUAL_MEMORY("fooba", out, 5);
  TEST_ASSERT_EQUAL_INT(4, base32_decode("mzxw6yq", 7, out, pos));  // "foob", either case
  TEST_ASSERT_EQUAL_MEMORY("foob", out, 4);
  TEST_ASSERT_EQUAL_INT(B32_BAD_LENGTH, base32_decode("MZXW6Y", 6, out, pos));
  TEST_ASSERT_EQUAL_UINT8(6, pos);
  TEST_ASSERT_EQUAL_INT(B32_BAD_TAIL, base32_decode("MZXW6YR", 7, out, pos));  // 'R' sets an unused bit
  TEST_ASSERT_EQUAL_UINT8(6, pos);
  TEST_ASSERT_EQUAL_INT(B32_BAD_CHAR, base32_decode("MZ0W", 4, out, pos));
  TEST_ASSERT_EQUAL_UINT8(2, pos);
}

static void test_crc_mismatch_keeps_old_map(void) {
  uint16_t n = FETCH(bkv_tiny);
  TEST_ASSERT_EQUAL_INT(UPLOAD_COMMITTED, upload(buf, n, false));
  n = FETCH(bkv_weights);
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_begin(n, bkv_weights_crc32 ^ 1, false));
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_chunk(0, buf, (uint8_t)n));
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 E"));
  EXPECT_IN_REPLY("Error:M721 CRC ");
  EXPECT_IN_REPLY(" != C");
  TEST_ASSERT_FALSE(up.open());
  TEST_ASSERT_EQUAL_UINT16(1, store.layer_count());
  TEST_ASSERT_EQUAL_UINT16(60, store.first_z());
  TEST_ASSERT_EQUAL_UINT8(0, store.info().flags);
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, send_chunk(0, buf, 5));
  EXPECT_REPLY("Error:M721 no upload open");
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 E"));
  EXPECT_REPLY("Error:M721 no upload open");
}

static void test_structure_error_keeps_old_map(void) {
  uint16_t n = FETCH(bkv_tiny);
  TEST_ASSERT_EQUAL_INT(UPLOAD_COMMITTED, upload(buf, n, false));
  // A record with a wrong CRC-8, sent with a correct CRC-32.
  buf[12] ^= 1;
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, upload(buf, n, false));
  EXPECT_REPLY("Error:M721 record_crc at byte 8");
  TEST_ASSERT_EQUAL_UINT16(1, store.layer_count());
  TEST_ASSERT_EQUAL_HEX8(0x90, store.records()[4]);  // the old first body byte
  // An append whose z does not continue.
  n = FETCH(bkv_tiny);
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, upload(buf + 8, (uint16_t)(n - 8), true));
  EXPECT_REPLY("Error:M721 z_order at byte 0");
  TEST_ASSERT_EQUAL_UINT16(1, store.layer_count());
}

static void test_size_mismatch(void) {
  const uint16_t n = FETCH(bkv_full_layer);
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_begin(n, bkv_full_layer_crc32, false));
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_chunk(0, buf, 40));
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 E"));
  EXPECT_REPLY("Error:M721 received 40/208");
  TEST_ASSERT_TRUE(up.open());  // the host may still send the rest
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, SEND("M721"));
  EXPECT_REPLY("echo:BulgeMap layers:0 bytes:0/2048 points:0 z:- upload:40/208");
  for (uint16_t off = 40; off < n; off += 40)
    TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_chunk(off, buf + off, (uint8_t)(n - off < 40 ? n - off : 40)));
  TEST_ASSERT_EQUAL_INT(UPLOAD_COMMITTED, SEND("M721 E"));
  // A map announced with the wrong size fails its CRC (different bytes) or its structure.
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_begin(n - 1, crc32_update(0, buf, n - 1), false));
  for (uint16_t off = 0; off < n - 1; off += 40)
    TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_chunk(off, buf + off, (uint8_t)(n - 1 - off < 40 ? n - 1 - off : 40)));
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 E"));
  EXPECT_REPLY("Error:M721 truncated at byte 8");
  TEST_ASSERT_EQUAL_UINT16(64, store.point_count());
}

static void test_too_large(void) {
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 S2057 C0"));
  EXPECT_REPLY("Error:M721 S2057 not in 8..2056");  // arena + header
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, SEND("M721 S2056 C0"));  // a full arena of records + header
  TEST_ASSERT_EQUAL_UINT16(2048, store.stage_size());
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 S7 C0"));
  EXPECT_REPLY("Error:M721 S7 not in 8..2056");  // shorter than the header
  TEST_ASSERT_TRUE(up.open());  // the failed begin left the open one alone
  TEST_ASSERT_EQUAL_UINT16(2056, up.size());
  // With a map in force, a replacement must fit beside it.
  TEST_ASSERT_EQUAL_INT(UPLOAD_COMMITTED, play(bkv_text_cylinder_m721) > 0 ? UPLOAD_COMMITTED : UPLOAD_ERROR);
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 S1000 C0"));
  EXPECT_REPLY("Error:M721 S1000 not in 8..502");  // 494 free + header
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, SEND("M721 S502 C0"));
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 S495 C0 A1"));
  EXPECT_REPLY("Error:M721 S495 not in 1..494");
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, SEND("M721 S494 C0 A1"));
  TEST_ASSERT_EQUAL_UINT16(34, store.layer_count());
}

static void test_append_needs_a_map(void) {
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 S10 C5 A1"));
  EXPECT_REPLY("Error:M721 A1 needs a map");
  TEST_ASSERT_FALSE(up.open());
}

static void test_argument_errors(void) {
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 S10 C5 Q1"));
  EXPECT_REPLY("Error:M721 unknown parameter Q");
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 S10 E"));
  EXPECT_REPLY("Error:M721 mixed actions");
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 X E"));
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 S0 C5"));
  EXPECT_REPLY("Error:M721 S0 not in 8..2056");
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 S65536 C5"));
  EXPECT_REPLY("Error:M721 S65536 not in 8..2056");
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 C5"));
  EXPECT_REPLY("Error:M721 S missing or bad");
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 S1x C5"));
  EXPECT_REPLY("Error:M721 S missing or bad");
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 S10"));
  EXPECT_REPLY("Error:M721 C missing or bad");
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 S10 C0x12"));
  EXPECT_REPLY("Error:M721 C missing or bad");
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 S10 C4294967296"));
  EXPECT_REPLY("Error:M721 C missing or bad");
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 S10 C1 A2"));
  EXPECT_REPLY("Error:M721 A2 not in 0..1");
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 S10 C1 A1x"));
  EXPECT_REPLY("Error:M721 A missing or bad");
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 D"));
  EXPECT_REPLY("Error:M721 no upload open");
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, SEND("M721 S10 C1 A0"));
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 DAA"));
  EXPECT_REPLY("Error:M721 O missing or bad");
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 O-1 DAA"));
  EXPECT_REPLY("Error:M721 O missing or bad");
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 O0 D"));
  EXPECT_REPLY("Error:M721 D missing or bad");
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 O0"));
  EXPECT_REPLY("Error:M721 D missing or bad");
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 O0 E"));
  EXPECT_REPLY("Error:M721 mixed actions");
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 X C1"));
  EXPECT_REPLY("Error:M721 mixed actions");
  TEST_ASSERT_TRUE(args.parse("M720 S1"));
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, up.handle(args, reply, sizeof reply));
  EXPECT_REPLY("Error:M721 got another code");
  TEST_ASSERT_TRUE(up.open());
  TEST_ASSERT_FALSE(store.loaded());
}

static void test_second_begin_drops_the_first(void) {
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, SEND("M721 S30 C1"));
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, SEND("M721 O0 DAAAAAAAA"));
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, SEND("M721 S20 C2"));
  EXPECT_REPLY("echo:M721 upload 5/30 dropped\necho:M721 receiving 20 bytes");
  TEST_ASSERT_EQUAL_UINT16(0, up.received());
  TEST_ASSERT_EQUAL_UINT16(12, store.stage_size());  // records; the header waits in MapUpload
}

static void test_clear_during_upload_and_store_changes(void) {
  uint16_t n = FETCH(bkv_tiny);
  TEST_ASSERT_EQUAL_INT(UPLOAD_COMMITTED, upload(buf, n, false));
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, SEND("M721 S20 C1"));
  TEST_ASSERT_EQUAL_INT(UPLOAD_CLEARED, SEND("M721 X"));
  TEST_ASSERT_FALSE(up.open());
  TEST_ASSERT_EQUAL_UINT16(0, store.stage_size());
  TEST_ASSERT_TRUE(store.empty());
  // Another path reloads the store while an upload is open: the upload is gone.
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, SEND("M721 S20 C1"));
  TEST_ASSERT_EQUAL_INT(MAP_OK, store.load(buf, n));
  TEST_ASSERT_FALSE(up.open());
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, SEND("M721 O0 DAA"));
}

static void test_append_while_printing_releases(void) {
  // Head map committed; the tail is streamed while layers are released mid-upload.
  TEST_ASSERT_EQUAL_INT(UPLOAD_COMMITTED, upload(buf, FETCH(bkv_tiny), false));
  // Tail: two records above 0.60 mm built from the tiny record with new z and CRC.
  uint8_t rec[24];
  uint8_t k = 0;
  for (uint16_t z = 90; z <= 120; z += 30) {
    memcpy(rec + k, buf + 8, 12);
    rec[k] = (uint8_t)z;
    rec[k + 1] = 0;
    rec[k + 11] = crc8(rec + k, 11);
    k = (uint8_t)(k + 12);
  }
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_begin(k, crc32_update(0, rec, k), true));
  EXPECT_REPLY("echo:M721 receiving 24 bytes (append)");
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_chunk(0, rec, 10));
  store.release_below(61);  // the printer finished 0.60 mm
  TEST_ASSERT_TRUE(store.empty());
  TEST_ASSERT_TRUE(up.open());
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, SEND("M721"));
  EXPECT_REPLY("echo:BulgeMap layers:0 bytes:0/2048 points:0 z:- upload:10/24 append");
  TEST_ASSERT_EQUAL_INT(UPLOAD_OK, send_chunk(10, rec + 10, 14));
  TEST_ASSERT_EQUAL_INT(UPLOAD_COMMITTED, SEND("M721 E"));
  EXPECT_REPLY("echo:BulgeMap layers:2 bytes:24/2048 points:6 z:0.90..1.20");
  TEST_ASSERT_EQUAL_MEMORY(rec, store.records(), 24);
}

static void test_short_reply_buffer_is_marked(void) {
  char small[24];
  memset(small, 'Z', sizeof small);
  strcpy(line, "M721 S2057 C0");
  TEST_ASSERT_TRUE(args.parse(line));
  TEST_ASSERT_EQUAL_INT(UPLOAD_ERROR, up.handle(args, small, 16));
  TEST_ASSERT_EQUAL_INT(15, (int)strlen(small));
  TEST_ASSERT_EQUAL_STRING("Error:M721 S...", small);
  TEST_ASSERT_EQUAL_INT('Z', small[16]);  // nothing written past the size given
}

int main(void) {
  UNITY_BEGIN();
  RUN_TEST(test_transcript_tiny);
  RUN_TEST(test_transcript_head_then_append);
  RUN_TEST(test_transcript_streams_a_map_larger_than_the_arena);
  RUN_TEST(test_happy_path_replies);
  RUN_TEST(test_resent_chunk_is_harmless);
  RUN_TEST(test_gap_is_an_error);
  RUN_TEST(test_bad_base32);
  RUN_TEST(test_crc_mismatch_keeps_old_map);
  RUN_TEST(test_structure_error_keeps_old_map);
  RUN_TEST(test_size_mismatch);
  RUN_TEST(test_too_large);
  RUN_TEST(test_append_needs_a_map);
  RUN_TEST(test_argument_errors);
  RUN_TEST(test_second_begin_drops_the_first);
  RUN_TEST(test_clear_during_upload_and_store_changes);
  RUN_TEST(test_append_while_printing_releases);
  RUN_TEST(test_short_reply_buffer_is_marked);
  return UNITY_END();
}
