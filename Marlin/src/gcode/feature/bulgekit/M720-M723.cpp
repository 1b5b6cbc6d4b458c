/**
 * bulgekit for Marlin: M720 (bulge settings), M721 (map upload), M722 (outer-wall
 * marker), M723 (width by feedrate), and their M503 reports.
 *
 * The handlers give the core the raw command text (parser.command_ptr) so the
 * same argument checks run here and in the core's unit tests; the core prints
 * "echo:" or "Error:" lines through Marlin's serial port as it decides (see
 * core/reply_text.h). Marlin sends "ok" after.
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

#if ENABLED(BULGE_MAP)

  /**
   * M720: bulge settings. S<mode 0|1|2> P<dwell ms> E<extra mm> T<tolerance mm>
   * No parameters: report. Bad input: one Error: line, nothing changes.
   */
  void GcodeSuite::M720() {
    bk::GcodeArgs args;
    if (!bk_parse(args)) return;
    bk::ReplyText r(nullptr, 0);
    if (BulgeKit::bulge.m720(args, r) && !args.none())
      BulgeKit::arc_rearm(BulgeKit::ARC_BULGE);  // new settings: a new print may start
    BulgeKit::end_reply(r);
  }

  void GcodeSuite::M720_report(const bool forReplay/*=true*/) {
    report_heading(forReplay, F("Bulge map (M720 S<mode> P<ms> E<mm> T<mm>)"));
    bk::ReplyText r(nullptr, 0);
    BulgeKit::bulge.report(r, !forReplay);
    BulgeKit::end_reply(r);
  }

  /**
   * M721: bulge map upload (begin S C [A1], chunk O D, commit E, clear X, status).
   * A committed full map (or a clear) makes the planner drop its decoded layer;
   * appended records need nothing (the current layer is unchanged).
   */
  void GcodeSuite::M721() {
    bk::GcodeArgs args;
    if (!bk_parse(args)) return;
    bk::ReplyText r(nullptr, 0);
    const bk::UploadStatus st = BulgeKit::upload.handle(args, r);
    if (st == bk::UPLOAD_CLEARED || (st == bk::UPLOAD_COMMITTED && !BulgeKit::upload.appending())) {
      BulgeKit::map_replaced();
      BulgeKit::arc_rearm(BulgeKit::ARC_BULGE);  // a new map: a new print
    }
    BulgeKit::end_reply(r);
  }

  /**
   * M722: outer-wall marker. S1 enter, S0 leave (inserted by the host at the
   * slicer's feature comments). Queued in order with the moves, so the split
   * decision of every G1 sees the marker state of its own place in the file.
   */
  void GcodeSuite::M722() {
    bk::GcodeArgs args;
    if (!bk_parse(args)) return;
    bk::ReplyText r(nullptr, 0);
    BulgeKit::bulge.m722(args, r);
    BulgeKit::end_reply(r);
  }

#endif // BULGE_MAP

#if ENABLED(WIDTH_BY_FEEDRATE)

  /**
   * M723: width by feedrate. S Q|R D H L U; no parameters: two report lines.
   */
  void GcodeSuite::M723() {
    bk::GcodeArgs args;
    if (!bk_parse(args)) return;
    bk::ReplyText r(nullptr, 0);
    if (BulgeKit::width.command(args, r) && !args.none())
      BulgeKit::arc_rearm(BulgeKit::ARC_WIDTH);
    BulgeKit::end_reply(r);
  }

  void GcodeSuite::M723_report(const bool forReplay/*=true*/) {
    report_heading(forReplay, F("Width by feedrate (M723)"));
    bk::ReplyText r(nullptr, 0);
    BulgeKit::width.report(r, !forReplay, false);  // the statistics line is for M723 alone
    BulgeKit::end_reply(r);
  }

#endif // WIDTH_BY_FEEDRATE

#endif // HAS_BULGEKIT
