// M721: the bulge map upload over a G-code text link (see docs/reference/mcodes.md).
//
//   M721 S<size> C<crc32> [A1]   begin (A1: the bytes are records to append)
//   M721 O<offset> D<base32>     chunk, <= 64 base32 chars (40 bytes) a line
//   M721 E                       commit: size, CRC-32 and structure checked
//   M721 X                       clear the map
//   M721                         status
//
// The record bytes are staged in the map arena's free space
// (MapStore::stage_open) and a new map's 8-byte header in this object, so an
// upload costs no RAM beyond this object (19 bytes on AVR) and the map in force
// is untouched until a commit passes every check. The catch: a replacement's
// records must fit beside the current map; if they do not, the Error's S range
// shows the room left and "M721 X" first frees the arena.
//
// Pure logic: the caller parses the line with GcodeArgs, passes it in and
// prints the reply text (Marlin glue: SERIAL_ECHOLN per line).
#ifndef BK_MAP_UPLOAD_H
#define BK_MAP_UPLOAD_H

#include <stdint.h>

#include "bulge_map.h"
#include "gcode_args.h"
#include "reply_text.h"

namespace bk {

enum UploadStatus : int8_t {
  UPLOAD_OK = 0,         // accepted (begin, chunk, status)
  UPLOAD_COMMITTED = 1,  // a new map or appended records are now in force
  UPLOAD_CLEARED = 2,    // the map was cleared
  UPLOAD_ERROR = -1,     // reply holds an "Error:" line; nothing changed
                         // (except: a commit that fails CRC or structure checks
                         // also closes the upload, the old map stays in force)
};

// Base32 (RFC 4648 alphabet, no padding, case-insensitive) as M721 D uses it.
enum Base32Error : int8_t { B32_BAD_CHAR = -1, B32_BAD_LENGTH = -2, B32_BAD_TAIL = -3 };
// Checks and decodes text in one pass into out (len * 5 / 8 bytes; written
// even when the text turns out bad). Returns the byte count, or a Base32Error
// with the offending char index in bad_pos (length errors: bad_pos = len).
int16_t base32_decode(const char *s, uint8_t len, uint8_t *out, uint8_t &bad_pos);

class MapUpload {
 public:
  explicit MapUpload(MapStore &store) : store_(store) {}  // head_ is written before it is read

  // Handles one parsed M721 line. The reply is zero or more lines separated by
  // '\n' (no trailing newline; nothing written = nothing to print). Never
  // prints "ok" (Marlin does).
  UploadStatus handle(const GcodeArgs &args, ReplyText &r);
#if !BK_REPLY_SERIAL
  // The same into a buffer (tests, tools): reply_size >= BK_M721_REPLY_BYTES.
  UploadStatus handle(const GcodeArgs &args, char *reply, uint16_t reply_size);
#endif

  // Open while size_ is set and the store still holds our staging (a clear or
  // load underneath closes it).
  bool open() const { return size_ && store_.stage_size() == stage_bytes(); }
  bool appending() const { return append_; }
  uint16_t size() const { return size_; }
  uint16_t received() const { return received_; }
  void abort();

 private:
  UploadStatus begin(const GcodeArgs &a, ReplyText &r);
  UploadStatus chunk(const GcodeArgs &a, ReplyText &r);
  UploadStatus commit(ReplyText &r);
  void status(ReplyText &r) const;

  uint8_t head_bytes() const { return append_ ? 0 : MAP_HEADER_BYTES; }  // bytes kept in head_
  uint16_t stage_bytes() const { return (uint16_t)(size_ - head_bytes()); }

  MapStore &store_;
  uint8_t head_[MAP_HEADER_BYTES];  // a new map's header while it is uploaded
  uint32_t crc_ = 0;
  uint16_t size_ = 0;      // 0: no upload
  uint16_t received_ = 0;  // contiguous bytes from offset 0
  bool append_ = false;
};

}  // namespace bk

#endif  // BK_MAP_UPLOAD_H
