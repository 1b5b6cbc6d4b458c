// M721 map upload. See map_upload.h and docs/mcodes.md.
#include "map_upload.h"

#include "reply_text.h"

namespace bk {

// ---- base32 ------------------------------------------------------------------------
static int8_t b32_value(char ch) {
  if (ch >= 'A' && ch <= 'Z') return (int8_t)(ch - 'A');
  if (ch >= 'a' && ch <= 'z') return (int8_t)(ch - 'a');
  if (ch >= '2' && ch <= '7') return (int8_t)(ch - '2' + 26);
  return -1;
}

int16_t base32_check(const char *s, uint8_t len, uint8_t &bad_pos) {
  for (uint8_t i = 0; i < len; i++)
    if (b32_value(s[i]) < 0) {
      bad_pos = i;
      return B32_BAD_CHAR;
    }
  // Unpadded groups end after 2, 4, 5 or 7 chars (1..4 bytes); the bits the
  // last char carries beyond the final byte must be zero (canonical form).
  static const uint8_t tail_bits[8] = {0, 0xFF, 2, 0xFF, 4, 1, 0xFF, 3};
  uint8_t t = tail_bits[len & 7];
  if (t == 0xFF) {
    bad_pos = len;
    return B32_BAD_LENGTH;
  }
  if (t && (b32_value(s[len - 1]) & ((1 << t) - 1))) {
    bad_pos = (uint8_t)(len - 1);
    return B32_BAD_TAIL;
  }
  return (int16_t)((uint16_t)len * 5 / 8);
}

void base32_decode(const char *s, uint8_t len, uint8_t *out) {
  uint16_t acc = 0;  // at most 7 + 5 pending bits
  uint8_t bits = 0;
  for (uint8_t i = 0; i < len; i++) {
    acc = (uint16_t)((acc << 5) | (uint8_t)b32_value(s[i]));
    bits += 5;
    if (bits >= 8) {
      bits -= 8;
      *out++ = (uint8_t)(acc >> bits);
    }
  }
}

// ---- M721 ------------------------------------------------------------------------------
void MapUpload::abort() {
  if (open_ && open()) store_.stage_close();
  open_ = false;
  size_ = received_ = 0;
}

UploadStatus MapUpload::handle(const GcodeArgs &a, char *reply, uint16_t reply_size) {
  ReplyText r(reply, reply_size);
  if (open_ && !open()) open_ = false;  // the store was cleared or reloaded underneath
  if (a.code_letter() != 'M' || a.code() != 721) {
    r.p(BK_F("Error:M721 handler got another command"));
    return UPLOAD_ERROR;
  }
  if (!check_words(a, "SCAODEX", BK_F("M721"), r)) return UPLOAD_ERROR;
  const uint8_t groups = (uint8_t)((a.has('S') || a.has('C') || a.has('A')) + (a.has('O') || a.has('D')) +
                                   a.has('E') + a.has('X'));
  if (groups > 1) {
    r.p(BK_F("Error:M721 mixes actions: send S/C/A, O/D, E or X alone"));
    return UPLOAD_ERROR;
  }
  if (a.has('S') || a.has('C') || a.has('A')) return begin(a, r);
  if (a.has('O') || a.has('D')) return chunk(a, r);
  if (a.has('E')) return commit(r);
  if (a.has('X')) {
    abort();
    store_.clear();
    r.p(BK_F("echo:BulgeMap cleared"));
    return UPLOAD_CLEARED;
  }
  status(r);
  return UPLOAD_OK;
}

UploadStatus MapUpload::begin(const GcodeArgs &a, ReplyText &r) {
  uint32_t size = 0, crc = 0, app = 0;
  if (a.get_ulong('S', size) != ARG_OK || size < 1 || size > 65535) {
    r.p(BK_F("Error:M721 S<size> missing or not 1..65535"));
    return UPLOAD_ERROR;
  }
  if (a.get_ulong('C', crc) != ARG_OK) {
    r.p(BK_F("Error:M721 C<crc32> missing or bad (decimal 0..4294967295)"));
    return UPLOAD_ERROR;
  }
  ArgStatus as = a.get_ulong('A', app);
  if (as == ARG_EMPTY) app = 1;  // a bare "A" reads as A1
  else if (as == ARG_BAD || app > 1) {
    r.p(BK_F("Error:M721 A must be 0 or 1"));
    return UPLOAD_ERROR;
  }
  // While an upload is open its bytes sit in the free space: measure the room
  // as if it were closed, since a new begin replaces it.
  const uint16_t room = store_.free_bytes();
  if (app) {
    if (!store_.loaded()) {
      r.p(BK_F("Error:M721 A1 needs a map loaded first (upload one without A1)"));
      return UPLOAD_ERROR;
    }
    if (size > room) {
      r.p(BK_F("Error:M721 append too large: "));
      r.u(size);
      r.p(BK_F(" bytes, "));
      r.u(room);
      r.p(BK_F(" free of "));
      r.u(store_.capacity());
      r.p(BK_F(" (release printed layers first)"));
      return UPLOAD_ERROR;
    }
  } else {
    if (size < MAP_HEADER_BYTES) {
      r.p(BK_F("Error:M721 S"));
      r.u(size);
      r.p(BK_F(" is shorter than the 8-byte map header"));
      return UPLOAD_ERROR;
    }
    const uint32_t records = size - MAP_HEADER_BYTES;
    if (records > store_.capacity()) {
      r.p(BK_F("Error:M721 map too large: "));
      r.u(size);
      r.p(BK_F(" bytes, at most "));
      r.u((uint32_t)store_.capacity() + MAP_HEADER_BYTES);
      r.p(BK_F(" (arena "));
      r.u(store_.capacity());
      r.p(BK_F(" + header 8)"));
      return UPLOAD_ERROR;
    }
    if (records > room) {
      r.p(BK_F("Error:M721 map too large to stage: "));
      r.u(records);
      r.p(BK_F(" record bytes, "));
      r.u(room);
      r.p(BK_F(" free of "));
      r.u(store_.capacity());
      r.p(BK_F("; M721 X first"));
      return UPLOAD_ERROR;
    }
  }
  if (open()) {
    r.p(BK_F("echo:M721 previous upload dropped at "));
    r.u(received_);
    r.c('/');
    r.u(size_);
    r.c('\n');
  }
  size_ = (uint16_t)size;
  crc_ = crc;
  received_ = 0;
  append_ = app != 0;
  store_.stage_open(stage_bytes());  // fits: checked above
  open_ = true;
  r.p(BK_F("echo:M721 receiving "));
  r.u(size);
  r.p(app ? BK_F(" bytes (append)") : BK_F(" bytes"));
  return UPLOAD_OK;
}

UploadStatus MapUpload::chunk(const GcodeArgs &a, ReplyText &r) {
  if (!open()) {
    r.p(BK_F("Error:M721 no upload open (send M721 S<size> C<crc32> first)"));
    return UPLOAD_ERROR;
  }
  uint32_t off = 0;
  if (a.get_ulong('O', off) != ARG_OK) {
    r.p(BK_F("Error:M721 O<offset> missing or bad"));
    return UPLOAD_ERROR;
  }
  const char *text;
  uint8_t len;
  if (!a.raw('D', text, len) || len == 0) {
    r.p(BK_F("Error:M721 D<base32> missing"));
    return UPLOAD_ERROR;
  }
  if (len > BK_M721_CHUNK_CHARS_MAX) {
    r.p(BK_F("Error:M721 D has "));
    r.u(len);
    r.p(BK_F(" chars, max "));
    r.u(BK_M721_CHUNK_CHARS_MAX);
    return UPLOAD_ERROR;
  }
  uint8_t pos = 0;
  int16_t n = base32_check(text, len, pos);
  if (n < 0) {
    r.p(n == B32_BAD_LENGTH ? BK_F("Error:M721 bad base32 length ") : BK_F("Error:M721 bad base32 at char "));
    r.u(n == B32_BAD_LENGTH ? len : pos);
    return UPLOAD_ERROR;
  }
  if (off > received_) {
    r.p(BK_F("Error:M721 gap: O"));
    r.u(off);
    r.p(BK_F(" but "));
    r.u(received_);
    r.p(BK_F(" bytes received"));
    return UPLOAD_ERROR;
  }
  if (off + (uint32_t)n > size_) {
    r.p(BK_F("Error:M721 O"));
    r.u(off);
    r.p(BK_F(" +"));
    r.u((uint32_t)n);
    r.p(BK_F(" bytes exceeds size "));
    r.u(size_);
    return UPLOAD_ERROR;
  }
  // A resent line rewrites the same bytes at the same offset: harmless. A new
  // map's header bytes go to head_, the rest into the arena's staging area.
  uint8_t bytes[(BK_M721_CHUNK_CHARS_MAX * 5 + 7) / 8];
  base32_decode(text, len, bytes);
  uint8_t *stage = store_.stage_data();
  for (uint8_t i = 0; i < (uint8_t)n; i++) {
    uint16_t at = (uint16_t)(off + i);
    if (append_) stage[at] = bytes[i];
    else if (at < MAP_HEADER_BYTES) head_[at] = bytes[i];
    else stage[at - MAP_HEADER_BYTES] = bytes[i];
  }
  if (off + (uint16_t)n > received_) received_ = (uint16_t)(off + (uint16_t)n);
  return UPLOAD_OK;
}

UploadStatus MapUpload::commit(ReplyText &r) {
  if (!open()) {
    r.p(BK_F("Error:M721 no upload open to commit"));
    return UPLOAD_ERROR;
  }
  if (received_ != size_) {  // stays open: the host may send the missing lines
    r.p(BK_F("Error:M721 size mismatch: "));
    r.u(received_);
    r.p(BK_F(" of "));
    r.u(size_);
    r.p(BK_F(" bytes received"));
    return UPLOAD_ERROR;
  }
  const uint32_t crc = append_ ? crc32_update(0, store_.stage_data(), size_)
                               : crc32_update(crc32_update(0, head_, MAP_HEADER_BYTES), store_.stage_data(),
                                              stage_bytes());
  if (crc != crc_) {
    r.p(BK_F("Error:M721 CRC mismatch: data "));
    r.u(crc);
    r.p(BK_F(", C"));
    r.u(crc_);
    r.p(BK_F("; previous map kept"));
    abort();
    return UPLOAD_ERROR;
  }
  MapError e = append_ ? store_.append(store_.stage_data(), size_)
                        : store_.load_parts(head_, store_.stage_data(), stage_bytes());
  if (e != MAP_OK) {
    r.p(append_ ? BK_F("Error:M721 records rejected: ") : BK_F("Error:M721 map rejected: "));
    r.p(map_error_text(e));
    r.p(BK_F(" at byte "));
    r.u(store_.error_offset());
    r.p(BK_F("; previous map kept"));
    abort();
    return UPLOAD_ERROR;
  }
  open_ = false;
  size_ = received_ = 0;
  status(r);
  return UPLOAD_COMMITTED;
}

void MapUpload::status(ReplyText &r) const {
  r.p(BK_F("echo:BulgeMap layers:"));
  r.u(store_.layer_count());
  r.p(BK_F(" bytes:"));
  r.u(store_.bytes_used());
  r.c('/');
  r.u(store_.capacity());
  r.p(BK_F(" points:"));
  r.u(store_.point_count());
  r.p(BK_F(" z:"));
  if (store_.empty()) {
    r.c('-');
  } else {
    r.decimal(store_.first_z(), 2);
    r.p(BK_F(".."));
    r.decimal(store_.last_z(), 2);
  }
  if (open()) {
    r.p(BK_F(" upload:"));
    r.u(received_);
    r.c('/');
    r.u(size_);
    if (append_) r.p(BK_F(" append"));
  }
}

}  // namespace bk
