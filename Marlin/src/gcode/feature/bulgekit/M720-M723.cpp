/**
 * bulgekit for Marlin: M720 (bulge settings), M721 (map upload), M722 (outer-wall
 * marker), M723 (width by feedrate), and their M503 reports.
 *
 * The handlers give the core the raw command text (parser.command_ptr) so the
 * same argument checks run here and in the core's unit tests; the core answers
 * with "echo:" or "Error:" lines, printed as they are. Marlin sends "ok" after.
 */
#include "../../../inc/MarlinConfig.h"
#include "../../../feature/bulgekit/bulgekit.h"

#if HAS_BULGEKIT

#include "../../gcode.h"

// Parses the current command's text; on failure prints an Error: and returns false.
static bool bk_parse(bk::GcodeArgs &args) {
  if (args.parse(parser.command_ptr)) return true;
  SERIAL_ECHOLNPGM("Error:cannot read the parameters of this command");
  return false;
}

// Prints a report line for M503: with forReplay the "echo:" prefix goes, so the
// line can be sent back as a command.
static void bk_report_line(const bool forReplay, const char *line) {
  const char *nl = strchr(line, '\n');
  const uint8_t n = nl ? nl - line : strlen(line);
  uint8_t i = 0;
  if (forReplay && strncmp_P(line, PSTR("echo:"), 5) == 0) i = 5;
  for (; i < n; ++i) SERIAL_CHAR(line[i]);
  SERIAL_EOL();
}

#if ENABLED(BULGE_MAP)

  /**
   * M720: bulge settings. S<mode 0|1|2> P<dwell ms> E<extra mm> T<tolerance mm>
   * No parameters: report. Bad input: one Error: line, nothing changes.
   */
  void GcodeSuite::M720() {
    bk::GcodeArgs args;
    if (!bk_parse(args)) return;
    char reply[BK_PLAN_REPLY_MAX];
    if (BulgeKit::bulge.m720(args, reply, sizeof(reply)) && !args.none())
      BulgeKit::arc_rearm(BulgeKit::ARC_BULGE);  // new settings: a new print may start
    BulgeKit::print_reply(reply);
  }

  void GcodeSuite::M720_report(const bool forReplay/*=true*/) {
    report_heading(forReplay, F("Bulge map (M720 S<mode> P<ms> E<mm> T<mm>)"));
    bk::GcodeArgs args;
    char cmd[8];
    BulgeKit::parse_P(args, cmd, PSTR("M720"));
    char reply[BK_PLAN_REPLY_MAX];
    BulgeKit::bulge.m720(args, reply, sizeof(reply));
    bk_report_line(forReplay, reply);
  }

  /**
   * M721: bulge map upload (begin S C [A1], chunk O D, commit E, clear X, status).
   * A committed full map (or a clear) makes the planner drop its decoded layer;
   * appended records need nothing (the current layer is unchanged).
   */
  void GcodeSuite::M721() {
    bk::GcodeArgs args;
    if (!bk_parse(args)) return;
    char reply[BK_M721_REPLY_BYTES];
    const bk::UploadStatus st = BulgeKit::upload.handle(args, reply, sizeof(reply));
    if (st == bk::UPLOAD_CLEARED || (st == bk::UPLOAD_COMMITTED && !BulgeKit::upload.appending())) {
      BulgeKit::map_replaced();
      BulgeKit::arc_rearm(BulgeKit::ARC_BULGE);  // a new map: a new print
    }
    BulgeKit::print_reply(reply);
  }

  /**
   * M722: outer-wall marker. S1 enter, S0 leave (inserted by the host at the
   * slicer's feature comments). Queued in order with the moves, so the split
   * decision of every G1 sees the marker state of its own place in the file.
   */
  void GcodeSuite::M722() {
    bk::GcodeArgs args;
    if (!bk_parse(args)) return;
    char reply[BK_PLAN_REPLY_MAX];
    BulgeKit::bulge.m722(args, reply, sizeof(reply));
    BulgeKit::print_reply(reply);
  }

#endif // BULGE_MAP

#if ENABLED(WIDTH_BY_FEEDRATE)

  /**
   * M723: width by feedrate. S Q|R D H L U; no parameters: two report lines.
   */
  void GcodeSuite::M723() {
    bk::GcodeArgs args;
    if (!bk_parse(args)) return;
    char reply[bk::WidthMode::REPLY_MIN];
    if (BulgeKit::width.command(args, reply, sizeof(reply)) && !args.none())
      BulgeKit::arc_rearm(BulgeKit::ARC_WIDTH);
    BulgeKit::print_reply(reply);
  }

  void GcodeSuite::M723_report(const bool forReplay/*=true*/) {
    report_heading(forReplay, F("Width by feedrate (M723)"));
    bk::GcodeArgs args;
    char cmd[8];
    BulgeKit::parse_P(args, cmd, PSTR("M723"));
    char reply[bk::WidthMode::REPLY_MIN];
    BulgeKit::width.command(args, reply, sizeof(reply));
    bk_report_line(forReplay, reply);  // the settings line; the statistics line is for M723 alone
  }

#endif // WIDTH_BY_FEEDRATE

#endif // HAS_BULGEKIT
