// libFuzzer target: M721 lines through GcodeArgs + MapUpload (begin, chunk
// with base32, commit, clear, status) against a MapStore.
//
// Input: text, one command per '\n'-separated line (cut at 95 chars, as
// Marlin's buffer would). A line "R<z>" calls release_below(z), standing in
// for layers consumed while printing. Checks: replies are NUL-terminated
// within the buffer and start with "echo:" or "Error:" (or are empty); an
// Error leaves the map in force unchanged; the store's counts stay consistent.
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "bulge_map.h"
#include "gcode_args.h"
#include "map_upload.h"

using namespace bk;

#define CHECK(c)       \
  do {                 \
    if (!(c)) abort(); \
  } while (0)

static MapStore store;
static MapUpload up(store);
static MapLayer layer;

static void consistent(void) {
  const uint8_t *p = store.records();
  uint16_t off = 0, layers = 0, points = 0;
  const bool w = store.info().flags & MAP_FLAG_WEIGHTS;
  while (off < store.bytes_used()) {
    uint16_t size = map_decode_record(p + off, (uint16_t)(store.bytes_used() - off), w, layer);
    CHECK(size > 0);
    layers++;
    points = (uint16_t)(points + layer.count);
    off = (uint16_t)(off + size);
  }
  CHECK(off == store.bytes_used());
  CHECK(layers == store.layer_count() && points == store.point_count());
  CHECK((uint32_t)store.bytes_used() + store.stage_size() <= store.capacity());
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  if (size > 8192) return 0;
  up.abort();
  store.clear();
  size_t i = 0;
  while (i < size) {
    size_t j = i;
    while (j < size && data[j] != '\n') j++;
    size_t len = j - i;
    if (len > 95) len = 95;
    // Exactly-sized heap copy: ASan flags any read beyond the terminator.
    char *line = (char *)malloc(len + 1);
    memcpy(line, data + i, len);
    line[len] = 0;
    i = j + 1;
    if (line[0] == 'R') {
      store.release_below(atol(line + 1));
      consistent();
      free(line);
      continue;
    }
    GcodeArgs a;
    if (a.parse(line) && a.code_letter() == 'M' && a.code() == 721) {
      const uint16_t used = store.bytes_used(), layers = store.layer_count();
      char reply[BK_M721_REPLY_BYTES + 1];
      reply[BK_M721_REPLY_BYTES] = 0x5A;  // guard byte
      UploadStatus st = up.handle(a, reply, BK_M721_REPLY_BYTES);
      CHECK(reply[BK_M721_REPLY_BYTES] == 0x5A);
      CHECK(memchr(reply, 0, BK_M721_REPLY_BYTES) != 0);
      if (st == UPLOAD_ERROR) {
        CHECK(strncmp(reply, "Error:", 6) == 0);
        CHECK(strchr(reply, '\n') == 0);  // one line
        CHECK(store.bytes_used() == used && store.layer_count() == layers);
      } else {
        CHECK(reply[0] == 0 || strncmp(reply, "echo:", 5) == 0);
      }
      if (st == UPLOAD_COMMITTED) CHECK(store.loaded());
      if (st == UPLOAD_CLEARED) CHECK(!store.loaded());
      if (up.open()) CHECK(up.received() <= up.size());
      if (st == UPLOAD_COMMITTED) consistent();  // the only change to the records
    }
    free(line);
  }
  consistent();
  return 0;
}
