"""Tests for install-marlin.py (the top-level installer) against a tiny synthetic Marlin tree.

The fake tree is generated here: each patched file holds filler lines and the
anchor lines the installer looks for (taken from the installer's own edit
table), never text copied from Marlin.
"""

import hashlib
import importlib.util
import os

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
_spec = importlib.util.spec_from_file_location("marlin_install", os.path.join(REPO, "install-marlin.py"))
mi = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(mi)


def fake_file_text(path, eol="\n"):
    """Filler, then every anchor of this file, separated by more filler."""
    lines = ["// synthetic stand-in for %s" % path, ""]
    for ed in mi.EDITS:
        if ed.path != path:
            continue
        lines += ["// filler before %s" % ed.name] + ed.anchor + ["// filler after %s" % ed.name, ""]
    return eol.join(lines) + eol


def make_tree(root, version="2.1.2.7", with_ini=True, eol="\n"):
    files = {mi.VERSION_H: '#pragma once\n#ifndef SHORT_BUILD_VERSION\n  #define SHORT_BUILD_VERSION "%s"\n#endif\n' % version,
             "Marlin/Configuration_adv.h": "#pragma once\n// options\n"}
    for ed in mi.EDITS:
        if ed.path == "ini/features.ini" and not with_ini:
            continue
        files[ed.path] = fake_file_text(ed.path, eol)
    for rel, text in files.items():
        full = os.path.join(root, rel)
        os.makedirs(os.path.dirname(full), exist_ok=True)
        with open(full, "w", encoding="utf-8", newline="") as f:
            f.write(text)
    os.makedirs(os.path.join(root, "Marlin", "src", "feature"), exist_ok=True)
    return root


def snapshot(root):
    """{relative path: sha256} of every file, plus the set of directories."""
    out, dirs = {}, set()
    for dirpath, dirnames, filenames in os.walk(root):
        dirs.add(os.path.relpath(dirpath, root))
        for fn in filenames:
            full = os.path.join(dirpath, fn)
            with open(full, "rb") as f:
                out[os.path.relpath(full, root)] = hashlib.sha256(f.read()).hexdigest()
    return out, dirs


def read(root, rel):
    with open(os.path.join(root, rel), encoding="utf-8", newline="") as f:
        return f.read()


def write(root, rel, text):
    with open(os.path.join(root, rel), "w", encoding="utf-8", newline="") as f:
        f.write(text)


def quiet(*_):
    pass


@pytest.fixture
def tree(tmp_path):
    return make_tree(str(tmp_path / "checkout"))


def test_install_puts_every_block_once_and_copies_files(tree):
    assert mi.install(tree, out=quiet)
    for ed in mi.EDITS:
        text = read(tree, ed.path)
        assert text.count("%s bulgekit:begin %s" % (ed.comment, ed.name)) == 1, (ed.path, ed.name)
        assert text.count("%s bulgekit:end %s" % (ed.comment, ed.name)) == 1, (ed.path, ed.name)
        first_body_line = [l for l in ed.text.split("\n") if l.strip()][0]
        if ed.regex:  # groups of the matched line filled in
            first_body_line = ed.regex.fullmatch(ed.anchor[0]).expand(first_body_line)
        assert first_body_line in text
    adv = read(tree, "Marlin/Configuration_adv.h")
    assert "// bulgekit:begin config" in adv and "#define BULGE_MAP" in adv
    assert adv.startswith("#pragma once\n// options\n")
    for rel, data in mi.files_to_copy():
        with open(os.path.join(tree, rel), "rb") as f:
            assert f.read() == data, rel
    core = os.path.join(tree, mi.CORE_DIR)
    assert os.path.isfile(os.path.join(core, "bulge_planner.h"))
    assert os.path.isfile(os.path.join(core, "bulgekit_config_defaults.h"))
    assert "MarlinConfigPre.h" in read(tree, mi.CORE_DIR + "/bulgekit_config.h")
    manifest = read(tree, mi.MANIFEST)
    assert "file " in manifest and "# Marlin 2.1.2.7" in manifest


def test_inserted_text_lands_at_the_anchor(tree):
    mi.install(tree, out=quiet)
    lines = read(tree, "Marlin/src/gcode/motion/G0_G1.cpp").split("\n")
    i = lines.index("    prepare_line_to_destination();")
    # the hook's if() sits right above the line it guards, inside the markers
    assert lines[i - 1].strip() == "// bulgekit:end line"
    assert "bulgekit.line_to_destination()" in lines[i - 3]
    gh = read(tree, "Marlin/src/gcode/gcode.h").split("\n")
    t = gh.index("  static void T(const int8_t tool_index);")
    assert gh[t - 1] == "  // bulgekit:end decls"


def test_replace_keeps_the_original_line_and_uninstall_restores_it(tree):
    mi.install(tree, out=quiet)
    text = read(tree, "Marlin/src/module/planner.h")
    original = "  bool is_move() { return !(is_sync() || is_page()); }"
    assert original not in text.split("\n")  # replaced ...
    assert "  // bulgekit:was |" + original in text.split("\n")  # ... but kept
    assert "|| is_dwell()" in text
    mi.uninstall(tree, out=quiet)
    assert original in read(tree, "Marlin/src/module/planner.h").split("\n")


def test_second_install_changes_nothing(tree):
    mi.install(tree, out=quiet)
    first = snapshot(tree)
    mtimes = {p: os.stat(os.path.join(tree, p)).st_mtime_ns for p in first[0]}
    messages = []
    mi.install(tree, out=messages.append)
    assert snapshot(tree) == first
    assert "0 file(s) patched, 0 copied" in messages[-1]
    # files whose content did not change are not rewritten (the manifest is)
    for p, t in mtimes.items():
        if p != mi.MANIFEST.replace("/", os.sep):
            assert os.stat(os.path.join(tree, p)).st_mtime_ns == t, p
    assert mi.install(tree, check_only=True, out=quiet) is False


def test_uninstall_restores_the_tree_byte_for_byte(tree):
    before = snapshot(tree)
    mi.install(tree, out=quiet)
    assert snapshot(tree) != before
    assert mi.uninstall(tree, out=quiet)
    assert snapshot(tree) == before
    assert mi.uninstall(tree, out=quiet) is False  # nothing left to remove


def test_update_replaces_an_outdated_block(tree):
    mi.install(tree, out=quiet)
    rel = "Marlin/src/gcode/host/M115.cpp"
    stale = read(tree, rel).replace('cap_line(F("BULGE_MAP")', 'cap_line(F("OLD_NAME")')
    write(tree, rel, stale)
    mi.install(tree, out=quiet)
    text = read(tree, rel)
    assert "OLD_NAME" not in text and text.count('cap_line(F("BULGE_MAP")') == 1


@pytest.mark.parametrize("damage", ["missing", "twice"])
def test_bad_anchor_refuses_and_writes_nothing(tree, damage):
    rel = "Marlin/src/module/stepper.cpp"
    anchor = "uint32_t Stepper::block_phase_isr() {"
    text = read(tree, rel)
    text = text.replace(anchor, "uint32_t Stepper::renamed_isr() {") if damage == "missing" else text + anchor + "\n"
    with open(os.path.join(tree, rel), "w", encoding="utf-8") as f:
        f.write(text)
    before = snapshot(tree)
    with pytest.raises(mi.InstallError) as e:
        mi.install(tree, out=quiet)
    msg = str(e.value)
    assert rel in msg and "'dwell-counter'" in msg and anchor in msg
    assert ("not found" in msg) if damage == "missing" else ("found 2 times" in msg)
    assert snapshot(tree) == before


def test_missing_hook_file_refuses(tree):
    os.remove(os.path.join(tree, "Marlin/src/gcode/host/M115.cpp"))
    before = snapshot(tree)
    with pytest.raises(mi.InstallError, match="M115.cpp: file missing"):
        mi.install(tree, out=quiet)
    assert snapshot(tree) == before


@pytest.mark.parametrize("version,ok", [("2.1.2", True), ("2.1.2.7", True), ("2.1.2.12", True),
                                        ("2.1.1", False), ("2.1.3", False), ("bugfix-2.1.x", False),
                                        ("2.1.2.7-custom", False)])
def test_version_gate(tmp_path, version, ok):
    root = make_tree(str(tmp_path / "t"), version=version)
    if ok:
        assert mi.install(root, out=quiet)
    else:
        with pytest.raises(mi.InstallError, match="2.1.2.x"):
            mi.install(root, out=quiet)
        assert not os.path.exists(os.path.join(root, mi.MANIFEST))


def test_any_version_still_checks_anchors(tmp_path):
    root = make_tree(str(tmp_path / "t"), version="2.1.3")
    warnings = []
    assert mi.install(root, any_version=True, out=warnings.append)
    assert any("warning" in w for w in warnings)


def test_no_ini_is_skipped_with_a_note(tmp_path):
    root = make_tree(str(tmp_path / "t"), with_ini=False)
    before = snapshot(root)
    notes = []
    mi.install(root, out=notes.append)
    assert any("ini/features.ini not present" in n for n in notes)
    assert not os.path.exists(os.path.join(root, "ini"))
    mi.uninstall(root, out=quiet)
    assert snapshot(root) == before


def test_ini_lines_use_hash_comments(tree):
    mi.install(tree, out=quiet)
    ini = read(tree, "ini/features.ini")
    assert "# bulgekit:begin features" in ini and "// bulgekit" not in ini
    assert "BULGE_MAP                              = build_src_filter=+<src/feature/bulgekit>" in ini


def test_crlf_files_stay_crlf(tmp_path):
    root = make_tree(str(tmp_path / "t"), eol="\r\n")
    before = snapshot(root)
    mi.install(root, out=quiet)
    text = read(root, "Marlin/src/gcode/gcode.cpp")
    assert "\r\n" in text and "\n" not in text.replace("\r\n", "")
    mi.uninstall(root, out=quiet)
    assert snapshot(root) == before


def test_uninstall_refuses_edited_copies_unless_forced(tree):
    before = snapshot(tree)
    mi.install(tree, out=quiet)
    edited = os.path.join(tree, "Marlin/src/feature/bulgekit/bulgekit.cpp")
    with open(edited, "a", encoding="utf-8") as f:
        f.write("// local change\n")
    installed = snapshot(tree)
    with pytest.raises(mi.InstallError, match="bulgekit.cpp"):
        mi.uninstall(tree, out=quiet)
    assert snapshot(tree) == installed
    mi.uninstall(tree, force=True, out=quiet)
    assert snapshot(tree) == before


def test_unbalanced_markers_are_reported(tree):
    mi.install(tree, out=quiet)
    rel = "Marlin/src/gcode/gcode.h"
    text = read(tree, rel).replace("  // bulgekit:end decls\n", "")
    write(tree, rel, text)
    with pytest.raises(mi.InstallError, match="gcode.h:.*'decls' has no end marker"):
        mi.uninstall(tree, out=quiet)


def test_locate_accepts_the_marlin_folder(tree):
    assert mi.locate(os.path.join(tree, "Marlin")) == os.path.abspath(tree)
    assert mi.locate(tree) == os.path.abspath(tree)
    with pytest.raises(mi.InstallError, match="not a Marlin checkout"):
        mi.locate(os.path.join(tree, "Marlin", "src"))


def test_main_exit_codes(tree, capsys):
    assert mi.main([tree, "--check"]) == 0
    assert not os.path.exists(os.path.join(tree, mi.MANIFEST))  # --check writes nothing
    assert mi.main([tree]) == 0
    assert mi.main([tree, "--uninstall"]) == 0
    os.remove(os.path.join(tree, mi.VERSION_H))
    assert mi.main([tree]) == 1
    assert "not a Marlin checkout" in capsys.readouterr().err


def settings_text(tree):
    return read(tree, "Marlin/src/module/settings.cpp")


@pytest.mark.parametrize("stock", ["V88", "V86", "V123"])
def test_eeprom_version_takes_the_b_letter_and_keeps_the_number(tree, stock):
    rel = "Marlin/src/module/settings.cpp"
    text = settings_text(tree).replace('#define EEPROM_VERSION "V88"', '#define EEPROM_VERSION "%s"' % stock)
    write(tree, rel, text)
    mi.install(tree, out=quiet)
    lines = settings_text(tree).split("\n")
    num = stock[1:]
    wanted = ('#define EEPROM_VERSION TERN(BULGE_MAP, "B%s", TERN(WIDTH_BY_FEEDRATE, "B%s", "V%s"))'
              " // bulgekit adds settings" % (num, num, num))
    assert wanted in lines
    # the stock define is only kept as a comment inside the block ...
    assert '#define EEPROM_VERSION "%s"' % stock not in lines
    assert '// bulgekit:was |#define EEPROM_VERSION "%s"' % stock in lines
    # ... and comes back on uninstall
    mi.uninstall(tree, out=quiet)
    assert settings_text(tree) == text


@pytest.mark.parametrize("damage", ["missing", "twice"])
def test_eeprom_version_line_must_be_unique(tree, damage):
    rel = "Marlin/src/module/settings.cpp"
    text = settings_text(tree)
    line = '#define EEPROM_VERSION "V88"'
    text = text.replace(line, '#define EEPROM_VERSION_X 1') if damage == "missing" else text + line + "\n"
    write(tree, rel, text)
    before = snapshot(tree)
    with pytest.raises(mi.InstallError) as e:
        mi.install(tree, out=quiet)
    msg = str(e.value)
    assert "'eeprom-version'" in msg and "a line matching" in msg
    assert ("not found" in msg) if damage == "missing" else ("found 2 times" in msg)
    assert snapshot(tree) == before


def test_eeprom_hooks_save_and_load_the_same_fields_in_the_same_order(tree):
    mi.install(tree, out=quiet)
    text = settings_text(tree)
    def block(name):
        a = text.index("bulgekit:begin %s" % name)
        return text[a:text.index("bulgekit:end %s" % name)]
    fields = [l.split()[1].rstrip(";") for l in block("eeprom-fields").split("\n")
              if "settings_t bulgekit_" in l]
    assert fields == ["bulgekit_m720", "bulgekit_m723"]
    for name, call in (("eeprom-save", "EEPROM_WRITE(line)"), ("eeprom-load", "EEPROM_READ(line)")):
        b = block(name)
        assert [f for f in fields if "_FIELD_TEST(%s)" % f in b] == fields
        assert b.index("_FIELD_TEST(bulgekit_m720)") < b.index("_FIELD_TEST(bulgekit_m723)")
        assert b.count(call) == 2
    # a validation pass (validating == true) reads but applies nothing
    assert block("eeprom-load").count("if (!validating) BulgeKit::settings_load(") == 2
    assert "BulgeKit::settings_reset();" in block("eeprom-reset")


def test_arc_hook_sits_right_before_plan_arc_and_includes_the_adapter(tree):
    mi.install(tree, out=quiet)
    rel = "Marlin/src/gcode/motion/G2_G3.cpp"
    lines = read(tree, rel).split("\n")
    call = "    plan_arc(destination, arc_offset, clockwise, circles_to_do);"
    i = lines.index(call)
    assert lines[i - 1] == "    // bulgekit:end arc-notice"
    block = lines[lines.index("    // bulgekit:begin arc-notice"):i]
    assert "      bulgekit.arc_notice();  // the arc is neither split nor retimed: say so once per print" in block
    assert block[1] == "    #if HAS_BULGEKIT" and block[-2] == "    #endif"
    inc = lines.index('#include "../../feature/bulgekit/bulgekit.h"')
    assert lines[inc - 1] == "// bulgekit:begin arc-include"
    assert lines[inc - 2] == '#include "../../module/temperature.h"'
    assert inc < i  # declared before use
    mi.uninstall(tree, out=quiet)
    assert "bulgekit" not in read(tree, rel)


def test_missing_arc_anchor_refuses_and_names_it(tree):
    rel = "Marlin/src/gcode/motion/G2_G3.cpp"
    text = read(tree, rel).replace("plan_arc(destination, arc_offset, clockwise, circles_to_do);",
                                   "plan_arc(destination, arc_offset, clockwise);")
    write(tree, rel, text)
    before = snapshot(tree)
    with pytest.raises(mi.InstallError) as e:
        mi.install(tree, out=quiet)
    assert rel in str(e.value) and "'arc-notice'" in str(e.value) and "not found" in str(e.value)
    assert snapshot(tree) == before


def test_deeper_nesting_is_found_and_the_hook_follows_it(tree):
    # 2.1.2.1 has G0_G1's body one level deeper (inside "if (IsRunning() ...)")
    path = os.path.join(tree, "Marlin/src/gcode/motion/G0_G1.cpp")
    text = read(tree, "Marlin/src/gcode/motion/G0_G1.cpp")
    ed = next(e for e in mi.EDITS if e.name == "line")
    deeper = "\n".join(("  " + l) if l.strip() else l for l in ed.anchor)
    with open(path, "w", encoding="utf-8", newline="") as f:
        f.write(text.replace("\n".join(ed.anchor), deeper))
    before = snapshot(tree)
    mi.install(tree, out=quiet)
    lines = read(tree, "Marlin/src/gcode/motion/G0_G1.cpp").split("\n")
    i = lines.index("      prepare_line_to_destination();")
    assert lines[i - 1] == "      // bulgekit:end line"
    hook = next(l for l in lines if "bulgekit.line_to_destination()" in l)
    assert hook.startswith("        if (")  # two columns deeper than in the edit table
    mi.uninstall(tree, out=quiet)
    assert snapshot(tree) == before


def test_an_alternative_anchor_is_used_when_the_first_is_missing(tree):
    ed = next(e for e in mi.EDITS if e.name == "eeprom-save")
    assert ed.alts, "eeprom-save carries 2.1.2.1's spelling"
    path = os.path.join(tree, ed.path)
    text = read(tree, ed.path)
    with open(path, "w", encoding="utf-8", newline="") as f:
        f.write(text.replace("\n".join(ed.anchor), "\n".join(ed.alts[0])))
    mi.install(tree, out=quiet)
    lines = read(tree, ed.path).split("\n")
    j = lines.index(ed.alts[0][2]) + 1  # the alternative's "#endif"
    assert lines[j] == ed.alts[0][3] and lines[j + 1].strip() == "// bulgekit:begin eeprom-save"


# ---- features off = stock ---------------------------------------------------------------
# Marlin's option macros, re-created here from what they do (ENABLED(X) is 1 for an
# option defined empty, 0 for one not defined), enough for the hook texts.
MACROS = r"""
#define _BK_ON_ ~, 1
#define _BK_SECOND(a, b, ...) b
#define _BK_IS(...) _BK_SECOND(__VA_ARGS__, 0)
#define _BK_EN(O) _BK_IS(_BK_ON_##O)
#define _BK_CAT(a, b) a##b
#define _BK_XCAT(a, b) _BK_CAT(a, b)
#define ENABLED(O) _BK_EN(O)
#define DISABLED(O) (!ENABLED(O))
#define ANY(A, B) (ENABLED(A) || ENABLED(B))
#define _BK_PICK_0(on, off) off
#define _BK_PICK_1(on, off) on
#define _BK_PICK(e, on, off) _BK_XCAT(_BK_PICK_, e)(on, off)
#define TERN(O, A, B) _BK_PICK(ENABLED(O), A, B)
#define TERN0(O, A) _BK_PICK(ENABLED(O), A, 0)
#define _BK_ARGS_0(...)
#define _BK_ARGS_1(...) __VA_ARGS__
#define _BK_COMMA_ARGS_1(...) , __VA_ARGS__
#define TERN_(O, ...) _BK_XCAT(_BK_ARGS_, ENABLED(O))(__VA_ARGS__)
#define OPTARG(O, ...) _BK_XCAT(_BK_ARGS_, ENABLED(O))(, __VA_ARGS__)
"""


def stub_headers(root):
    """Marlin's own headers are not in the fake tree: an empty stand-in for
    every quoted include that is missing, also for what the copied files
    include (until no include is missing), and the option macros' prelude."""
    import re
    new = True
    while new:
        new = False
        for dirpath, _, names in os.walk(root):
            for name in names:
                if not name.endswith((".h", ".cpp")):
                    continue
                with open(os.path.join(dirpath, name), encoding="utf-8") as f:
                    incs = re.findall(r'#include "([^"]+)"', f.read())
                for inc in incs:
                    path = os.path.normpath(os.path.join(dirpath, inc))
                    if not os.path.exists(path):
                        os.makedirs(os.path.dirname(path), exist_ok=True)
                        open(path, "w").close()
                        new = True
    with open(os.path.join(root, "bk_macros.h"), "w") as f:
        f.write(MACROS)


def preprocess(root, rel, defines, hooked=True):
    """The file as the compiler sees it (gcc -E -P), in a tree stub_headers()
    has prepared."""
    import re
    import shutil
    import subprocess
    full = os.path.join(root, rel)
    text = read(root, rel)
    # The fake files hold anchors cut out of context (an #if without its
    # #endif): such lines become comments, the same in both trees.
    # Outside the installed blocks every line is filler or anchor.
    lines, inside = [], False
    for l in text.split("\n"):
        if "bulgekit:begin" in l or "bulgekit:end" in l:
            inside = "bulgekit:begin" in l
        elif hooked and not inside and re.match(r"\s*#\s*(if|ifdef|ifndef|else|elif|endif)\b", l):
            l = "// anchor " + l
        lines.append(l)
    text = "\n".join(lines)
    prelude = os.path.join(root, "bk_macros.h")
    # a use of the EEPROM version string, so its value shows in the output
    probe = full + ".probe.cpp"
    with open(probe, "w", encoding="utf-8") as f:
        f.write(text + '\n#ifdef EEPROM_VERSION\nconst char v[] = EEPROM_VERSION;\n#endif\n')
    gxx = shutil.which("g++") or shutil.which("gcc")
    args = [gxx, "-E", "-P", "-x", "c++", "-include", prelude] + ["-D%s=" % d for d in defines] + [probe]
    run = subprocess.run(args, capture_output=True, text=True)
    assert run.returncode == 0, "%s: %s" % (rel, run.stderr)
    out = run.stdout
    os.remove(probe)
    # tokens as the compiler reads them: blank space does not count
    return [" ".join(l.split()) for l in out.split("\n") if l.strip() and l.strip() != "#pragma once"]


def test_both_features_off_compile_to_the_stock_sources(tree, tmp_path):
    """With BULGE_MAP and WIDTH_BY_FEEDRATE off, every hooked Marlin file reads
    to the compiler exactly as before the install (M115's caps included), and
    the copied files compile to nothing."""
    import shutil
    stock = str(tmp_path / "stock")
    shutil.copytree(tree, stock)
    mi.install(tree, out=quiet)
    stub_headers(tree)
    stub_headers(stock)
    hooked = sorted({ed.path for ed in mi.EDITS if ed.path.endswith((".cpp", ".h"))})
    assert "Marlin/src/gcode/host/M115.cpp" in hooked
    for rel in hooked:
        assert preprocess(tree, rel, []) == preprocess(stock, rel, []), rel
    copied = [rel for rel, _ in mi.files_to_copy() if rel.endswith(".cpp") and not rel.startswith(mi.CORE_DIR)]
    assert copied
    for rel in copied:
        assert preprocess(tree, rel, [], hooked=False) == [], rel
    # and the check is not blind: each feature on changes M115's caps
    for feature in ("BULGE_MAP", "WIDTH_BY_FEEDRATE"):
        on = preprocess(tree, "Marlin/src/gcode/host/M115.cpp", [feature])
        assert any('F("%s"), 1' % feature in l.replace(" ", "").replace(",1", ", 1") for l in on), on
        assert on != preprocess(stock, "Marlin/src/gcode/host/M115.cpp", [feature])


def test_config_block_with_both_features_off_defines_nothing(tmp_path):
    import subprocess
    import shutil
    text = mi.config_edit().text
    for f in ("BULGE_MAP", "WIDTH_BY_FEEDRATE"):
        assert "\n#define %s\n" % f in text
        text = text.replace("\n#define %s\n" % f, "\n//#define %s\n" % f)
    src = tmp_path / "block.h"
    src.write_text(MACROS + "\n#define BK_MACROS_END\n" + text)
    gxx = shutil.which("g++") or shutil.which("gcc")
    out = subprocess.run([gxx, "-E", "-dM", "-x", "c++", str(src)], capture_output=True, text=True, check=True).stdout
    base = subprocess.run([gxx, "-E", "-dM", "-x", "c++", "-"], input=MACROS + "\n#define BK_MACROS_END\n",
                          capture_output=True, text=True, check=True).stdout
    assert set(out.split("\n")) - set(base.split("\n")) == set()
