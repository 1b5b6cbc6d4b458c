"""Compact bulge map v1 on the host: vectors byte for byte, round trips,
corrupt input, M721 lines. The same vectors drive the firmware suites
(test/test_map_codec, test/test_map_upload) through test/vectors/vectors.h."""

from __future__ import annotations

import base64
import json
import re
import subprocess
import sys
import zlib
from pathlib import Path

import pytest

HOST = Path(__file__).resolve().parents[2]
ROOT = HOST.parent
VECTORS = ROOT / "test" / "vectors"
if str(HOST) not in sys.path:
    sys.path.insert(0, str(HOST))

from bulgekit.bulge import mapformat as mf  # noqa: E402

MAP_JSONS = sorted(p for p in VECTORS.glob("*.json") if json.loads(p.read_text())["kind"] == "map")
BAD_JSONS = sorted(p for p in VECTORS.glob("*.json") if json.loads(p.read_text())["kind"] == "bad")


def load(p: Path) -> tuple[dict, bytes]:
    d = json.loads(p.read_text())
    return d, (VECTORS / d["file"]).read_bytes()


def layers_from_json(d: dict) -> list[mf.Layer]:
    return [
        mf.Layer(
            layer["z_cmm"],
            tuple(tuple(p) for p in layer["points"]),
            tuple(layer["weights"]) if "weights" in layer else None,
        )
        for layer in d["layers"]
    ]


# ---- vectors ---------------------------------------------------------------------------------
def test_vector_set_is_complete():
    names = {p.name for p in VECTORS.iterdir()}
    assert len(MAP_JSONS) >= 7 and len(BAD_JSONS) >= 15
    for p in MAP_JSONS + BAD_JSONS:
        assert json.loads(p.read_text())["file"] in names
    assert "README.md" in names and "vectors.h" in names


@pytest.mark.parametrize("path", MAP_JSONS, ids=lambda p: p.stem)
def test_encoder_reproduces_vector_bytes(path):
    d, data = load(path)
    h = d["header"]
    m = mf.BulgeMap(h["quantum_um"], h["layer_height_cmm"], bool(h["flags"] & 1), layers_from_json(d))
    assert mf.encode_map_q(m) == data
    assert d["size"] == len(data) and d["crc32"] == zlib.crc32(data)


@pytest.mark.parametrize("path", MAP_JSONS, ids=lambda p: p.stem)
def test_decoder_matches_vector_json(path):
    d, data = load(path)
    m = mf.decode_map(data, source=d["file"])
    assert (m.version, m.flags, m.quantum_um, m.layer_height_cmm) == tuple(
        d["header"][k] for k in ("version", "flags", "quantum_um", "layer_height_cmm")
    )
    assert m.layers == layers_from_json(d)
    assert m.point_count == d["point_count"]


@pytest.mark.parametrize("path", BAD_JSONS, ids=lambda p: p.stem)
def test_corrupt_vectors_rejected_with_expected_code(path):
    d, data = load(path)
    with pytest.raises(mf.MapFormatError) as ei:
        mf.decode_map(data, source=d["file"])
    assert ei.value.code == d["expect_error"], str(ei.value)
    assert d["file"] in str(ei.value)  # the message names the file


def test_append_records_vector():
    d, tail = load(VECTORS / "text_cylinder_tail.json")
    head = (VECTORS / "text_cylinder_head.bkm").read_bytes()
    full = (VECTORS / "text_cylinder.bkm").read_bytes()
    assert head + tail == full  # records are self-contained: concatenation is a valid map
    got = mf.decode_records(tail, has_weights=False, after_z_cmm=d["after_z_cmm"])
    assert got == layers_from_json(d)
    with pytest.raises(mf.ZOrderError):  # appended below the head's last layer
        mf.decode_records(tail, has_weights=False, after_z_cmm=d["layers"][0]["z_cmm"])


def test_generator_output_is_current(tmp_path):
    """A fresh run of the generator writes exactly the committed files."""
    gen = ROOT / "tools" / "vectors" / "gen_vectors.py"
    subprocess.run([sys.executable, str(gen), "--out", str(tmp_path)], check=True, capture_output=True)
    fresh = sorted(p.name for p in tmp_path.iterdir())
    assert fresh == sorted(p.name for p in VECTORS.iterdir() if p.name != "README.md")
    for name in fresh:
        assert (tmp_path / name).read_bytes() == (VECTORS / name).read_bytes(), name


def _c_arrays(text: str) -> dict[str, bytes]:
    out = {}
    for m in re.finditer(r"static const uint8_t (bkv_\w+)\[(\d+)\] BKV_FLASH = \{(.*?)\};", text, re.S):
        vals = bytes(int(v, 16) for v in re.findall(r"0x([0-9A-F]{2})", m.group(3)))
        assert len(vals) == int(m.group(2)), m.group(1)
        out[m.group(1)] = vals
    return out


def _c_strings(text: str) -> dict[str, str]:
    out = {}
    for m in re.finditer(r"static const char (bkv_\w+)_m721\[\] BKV_FLASH =\n(.*?);\n", text, re.S):
        parts = re.findall(r'"((?:[^"\\]|\\.)*)"', m.group(2))
        out[m.group(1)] = "".join(p.replace("\\n", "\n").replace('\\"', '"').replace("\\\\", "\\") for p in parts)
    return out


def test_cpp_header_holds_the_vector_bytes():
    """vectors.h (what the firmware suites test) equals the .bkm/.m721 files."""
    text = (VECTORS / "vectors.h").read_text()
    arrays = _c_arrays(text)
    embedded = [k for k in arrays if k != "bkv_bad_blob"]
    assert len(embedded) >= 6
    for ident in embedded:
        assert arrays[ident] == (VECTORS / (ident[4:] + ".bkm")).read_bytes(), ident
    bad = re.findall(r"\{(\d+), (\d+), bk::MAP_ERR_(\w+)\},  // (\S+)", text)
    assert len(bad) == len(BAD_JSONS)
    for off, n, code, name in bad:
        d = json.loads((VECTORS / name).with_suffix(".json").read_text())
        assert arrays["bkv_bad_blob"][int(off) : int(off) + int(n)] == (VECTORS / name).read_bytes()
        assert code.lower() == d["expect_error"]
    strings = _c_strings(text)
    assert set(strings) == {"bkv_" + p.stem for p in VECTORS.glob("*.m721")}
    for ident, s in strings.items():
        assert s == (VECTORS / (ident[4:] + ".m721")).read_text(), ident


def test_cpp_error_names_match_python_codes():
    header = (ROOT / "src" / "bulge_map.h").read_text()
    cpp = {m.lower() for m in re.findall(r"MAP_ERR_(\w+) = -\d+", header)}
    py = {c.code for c in vars(mf).values() if isinstance(c, type) and issubclass(c, mf.MapFormatError)}
    assert py - {"input"} <= cpp
    assert cpp - py == {"no_header"}  # a firmware-only state


# ---- transcripts ---------------------------------------------------------------------------------
def _transcript_commands(text: str):
    """(release_below or None, line) pairs of a .m721 file."""
    for line in text.splitlines():
        m = re.match(r"; @release_below (\d+)$", line)
        if m:
            yield int(m.group(1)), None
        elif line and not line.startswith(";"):
            yield None, line


def _decode_lines(lines: list[str]) -> list[tuple[bytes, bool]]:
    """Plays M721 lines as the firmware would: returns each committed payload."""
    out, buf, size, crc, append = [], None, 0, 0, False
    expect_n = None
    for line in lines:
        body, _, cs = line.partition("*")
        assert mf.line_checksum(body) == int(cs)
        n, cmd = body.split(" ", 1)
        if expect_n is not None:
            assert int(n[1:]) == expect_n
        expect_n = int(n[1:]) + 1
        words = dict((w[0], w[1:]) for w in cmd.split()[1:])
        if "S" in words:
            size, crc, append, buf = int(words["S"]), int(words["C"]), words.get("A") == "1", bytearray()
        elif "O" in words:
            assert int(words["O"]) == len(buf)
            d = words["D"]
            buf += base64.b32decode(d + "=" * (-len(d) % 8))
        else:
            assert list(words) == ["E"] and len(buf) == size and zlib.crc32(buf) == crc
            out.append((bytes(buf), append))
    return out


def test_transcripts_match_builder_and_rebuild_the_maps():
    tiny = (VECTORS / "tiny.bkm").read_bytes()
    lines = [ln for _, ln in _transcript_commands((VECTORS / "tiny.m721").read_text())]
    assert lines == mf.upload_lines(tiny, start_line=1)
    assert _decode_lines(lines) == [(tiny, False)]

    lines = [ln for _, ln in _transcript_commands((VECTORS / "text_cylinder.m721").read_text())]
    (head, a0), (tail, a1) = _decode_lines(lines)
    assert (a0, a1) == (False, True)
    assert head + tail == (VECTORS / "text_cylinder.bkm").read_bytes()

    # The stream rebuilds text_tall.bkm, a map larger than the arena.
    lines = [ln for _, ln in _transcript_commands((VECTORS / "text_tall_stream.m721").read_text()) if ln]
    releases = [z for z, ln in _transcript_commands((VECTORS / "text_tall_stream.m721").read_text()) if z]
    chunks = _decode_lines(lines)
    full = (VECTORS / "text_tall.bkm").read_bytes()
    assert b"".join(d for d, _ in chunks) == full
    assert [a for _, a in chunks] == [False] + [True] * (len(chunks) - 1)
    assert len(releases) >= 2 and releases == sorted(releases)
    assert len(full) > 2048 + mf.HEADER_BYTES


def test_stream_plan_fits_the_arena():
    """Replay releases and appends against the record sizes: never above 2048 bytes."""
    text = (VECTORS / "text_tall_stream.m721").read_text()
    held: list[tuple[int, int]] = []
    pending: list[str] = []

    def commit(lines):
        for data, append in _decode_lines(lines):
            recs = data[mf.HEADER_BYTES :] if not append else data
            m = mf.decode_records(recs, has_weights=False)
            pos = 0
            for layer in m:
                size = len(mf.encode_record(layer, False))
                held.append((layer.z_cmm, size))
                pos += size
            assert pos == len(recs)
            assert sum(s for _, s in held) <= 2048

    for rel, line in _transcript_commands(text):
        if rel is not None:
            commit(pending)
            pending = []
            held[:] = [(z, s) for z, s in held if z >= rel]
        else:
            pending.append(line)
            if line.endswith("M721 E") or " M721 E*" in line:
                commit(pending)
                pending = []
    assert not pending and held


# ---- encoder / decoder behaviour -----------------------------------------------------------------
def test_worked_example_bytes():
    data = mf.encode_map([(0.6, [(10.0, 0.0), (9.95, 1.0), (9.8, 2.0)])])
    assert data.hex(" ") == "42 4b 4d 01 00 32 1e 1d 3c 00 03 07 90 03 00 01 28 05 28 d7"
    assert data[:8] == b"BKM\x01\x00\x32\x1e" + bytes([mf.crc8(b"BKM\x01\x00\x32\x1e")])
    assert data[8:] == bytes.fromhex("3c00 03 07 9003 00 01 28 05 28") + bytes([mf.crc8(data[8:-1])])
    assert data == (VECTORS / "tiny.bkm").read_bytes()


def test_crc_and_varint_primitives():
    assert mf.crc8(b"123456789") == 0xF4  # CRC-8/SMBUS check value
    assert mf.crc32(b"123456789") == 0xCBF43926
    assert [mf.varint(v) for v in (0, 127, 128, 16383, 16384, (1 << 21) - 1)] == [
        b"\x00",
        b"\x7f",
        b"\x80\x01",
        b"\xff\x7f",
        b"\x80\x80\x01",
        b"\xff\xff\x7f",
    ]
    with pytest.raises(mf.MapFormatError):
        mf.varint(1 << 21)
    for v in (0, 1, -1, 32767, -32768, 65535, -65535):
        assert mf.unzigzag(mf.zigzag(v)) == v
    assert [mf.zigzag(v) for v in (0, -1, 1, -2)] == [0, 1, 2, 3]


def test_round_trip_mm_with_weights():
    layers = [(0.3, [(-1.0, 2.0), (1.0, 2.05)]), (0.6, [(3.2, -4.4)])]
    data = mf.encode_map(layers, quantum_um=25, layer_height_mm=0.2, weights=[[0, 255], [17]])
    m = mf.decode_map(data)
    assert m.has_weights and m.quantum_um == 25 and m.layer_height_cmm == 20
    assert [layer.z_cmm for layer in m.layers] == [30, 60]
    assert m.layers[0].points == ((-40, 80), (40, 82))
    flat = [c for p in m.points_mm(m.layers[0]) for c in p]
    assert flat == pytest.approx([-1.0, 2.0, 1.0, 2.05])
    assert m.layers[0].weights == (0, 255) and m.layers[1].weights == (17,)
    assert mf.encode_map_q(m) == data


def test_rounding_is_half_away_from_zero():
    m = mf.decode_map(mf.encode_map([(0.3, [(0.025, -0.025), (0.0749, -0.0751)])]))
    assert m.layers[0].points == ((1, -1), (1, -2))


@pytest.mark.parametrize(
    "kwargs, exc",
    [
        (dict(layers=[(0.3, [])]), mf.CountZeroError),
        (dict(layers=[(0.3, [(0.0, 0.0)] * 65)]), mf.CountMaxError),
        (dict(layers=[(0.3, [(1638.4, 0.0)])]), mf.CoordinateError),  # 32768 quanta
        (dict(layers=[(0.3, [(0.0, -1638.45)])]), mf.CoordinateError),
        (dict(layers=[(0.6, [(0, 0)]), (0.6, [(0, 0)])]), mf.ZOrderError),
        (dict(layers=[(0.6, [(0, 0)]), (0.3, [(0, 0)])]), mf.ZOrderError),
        (dict(layers=[(655.36, [(0, 0)])]), mf.ZOrderError),
        (dict(layers=[(0.3, [(float("nan"), 0)])]), mf.CoordinateError),
        (dict(layers=[(0.3, [(0, 0)])], quantum_um=0), mf.HeaderValueError),
        (dict(layers=[(0.3, [(0, 0)])], layer_height_mm=0.125), mf.HeaderValueError),
        (dict(layers=[(0.3, [(0, 0)])], layer_height_mm=2.56), mf.HeaderValueError),
        (dict(layers=[(0.3, [(0, 0)])], weights=[[256]]), mf.MapFormatError),
        (dict(layers=[(0.3, [(0, 0)])], weights=[[1, 2]]), mf.MapFormatError),
        (dict(layers=[(0.3, [(0, 0)])], weights=[]), mf.MapFormatError),
    ],
)
def test_encoder_refuses_bad_input(kwargs, exc):
    with pytest.raises(exc):
        mf.encode_map(**kwargs)


def test_encoder_limits_accepted():
    data = mf.encode_map([(655.35, [(1638.35, -1638.4)] + [(0.0, 0.0)] * 63)], layer_height_mm=2.55)
    m = mf.decode_map(data)
    assert m.layers[0].z_cmm == 65535 and m.layers[0].points[0] == (32767, -32768)
    assert len(m.layers[0].points) == 64


def test_every_truncation_of_a_map_is_rejected():
    data = (VECTORS / "weights.bkm").read_bytes()
    boundaries = {8}
    pos = 8
    for layer in mf.decode_map(data).layers:
        pos += len(mf.encode_record(layer, True))
        boundaries.add(pos)
    for n in range(len(data)):
        if n in boundaries:
            mf.decode_map(data[:n])  # ends between records: a valid, shorter map
        else:
            with pytest.raises(mf.MapTruncatedError):
                mf.decode_map(data[:n])


def test_every_single_bit_flip_is_detected():
    data = (VECTORS / "text_cylinder_head.bkm").read_bytes()
    for i in range(len(data)):
        for bit in range(8):
            bad = bytearray(data)
            bad[i] ^= 1 << bit
            with pytest.raises(mf.MapFormatError):
                mf.decode_map(bytes(bad))


def test_decoder_errors_name_source_and_offset():
    data = bytearray((VECTORS / "weights.bkm").read_bytes())
    second = 8 + len(mf.encode_record(mf.decode_map(bytes(data)).layers[0], True))
    data[-2] ^= 0x40
    with pytest.raises(mf.RecordCRCError, match=rf"^maps/w\.bkm: byte {second}: record: CRC mismatch"):
        mf.decode_map(bytes(data), source="maps/w.bkm")


def test_firmware_point_limit_is_a_parameter():
    data = mf.encode_map([(0.3, [(float(i), 0.0) for i in range(10)])])
    mf.decode_map(data)
    with pytest.raises(mf.CountMaxError):
        mf.decode_map(data, max_points=8)


def test_encode_records_checks_order_against_the_live_map():
    recs = mf.encode_records([(0.9, [(1.0, 1.0)])], after_z_mm=0.6)
    assert mf.decode_records(recs, has_weights=False, after_z_cmm=60)[0].z_cmm == 90
    with pytest.raises(mf.ZOrderError):
        mf.encode_records([(0.9, [(1.0, 1.0)])], after_z_mm=0.9)
    wrec = mf.encode_records([(0.9, [(1.0, 1.0)])], weights=[[9]])
    assert mf.decode_records(wrec, has_weights=True)[0].weights == (9,)
    with pytest.raises(mf.LengthError):
        mf.decode_records(wrec, has_weights=False)


# ---- M721 lines -----------------------------------------------------------------------------------
def test_upload_lines_plain_and_numbered():
    data = (VECTORS / "text_cylinder.bkm").read_bytes()
    plain = mf.upload_lines(data)
    assert plain[0] == f"M721 S{len(data)} C{zlib.crc32(data)}"
    assert plain[-1] == "M721 E"
    assert len(plain) == 2 + -(-len(data) // 40)
    numbered = mf.upload_lines(data, start_line=998)
    assert numbered[0].startswith("N998 M721 S") and numbered[-1].startswith(f"N{998 + len(plain) - 1} M721 E*")
    for p, n in zip(plain, numbered):
        body, cs = n.rsplit("*", 1)
        assert body.endswith(p) and mf.line_checksum(body) == int(cs)
    assert _decode_lines(numbered) == [(data, False)]


@pytest.mark.parametrize("start", [None, 0, 1, 99999, 10**9])
def test_upload_line_length_limit(start):
    data = (VECTORS / "text_tall.bkm").read_bytes()  # offsets into the thousands
    big = mf.encode_map([(0.3 * (k + 1), [(float(i), float(-i)) for i in range(64)]) for k in range(200)])
    for d in (data, big):
        for line in mf.upload_lines(d, start_line=start):
            assert len(line) <= mf.LINE_MAX
            chunk = re.search(r" D([A-Z2-7]+)", line)
            assert chunk is None or len(chunk.group(1)) <= 64


def test_upload_lines_validate_payload():
    data = (VECTORS / "bad_record_crc.bkm").read_bytes()
    with pytest.raises(mf.RecordCRCError):
        mf.upload_lines(data)
    tail = (VECTORS / "text_cylinder_tail.bkr").read_bytes()
    assert mf.upload_lines(tail, append=True)[0].endswith(" A1")
    with pytest.raises(mf.MapFormatError):
        mf.upload_lines(tail)  # records are not a map
    with pytest.raises(mf.MapFormatError):
        mf.upload_lines(tail[:-1], append=True)
    with pytest.raises(mf.MapFormatError):
        mf.upload_lines(b"")


def test_upload_lines_checked_skips_only_the_decode():
    """checked=True (data cut from a map decoded already, as annotate does): the same lines, and
    the data not decoded again; the other checks stay."""
    data = (VECTORS / "text_cylinder.bkm").read_bytes()
    tail = (VECTORS / "text_cylinder_tail.bkr").read_bytes()
    assert mf.upload_lines(data, checked=True) == mf.upload_lines(data)
    assert mf.upload_lines(tail, append=True, checked=True) == mf.upload_lines(tail, append=True)
    bad = (VECTORS / "bad_record_crc.bkm").read_bytes()
    assert mf.upload_lines(bad, checked=True)[0] == f"M721 S{len(bad)} C{zlib.crc32(bad)}"
    with pytest.raises(mf.MapFormatError):
        mf.upload_lines(b"", checked=True)


def test_realistic_case_bytes_per_point(capsys):
    d, data = load(VECTORS / "text_cylinder.json")
    bpp = len(data) / d["point_count"]
    framing = mf.HEADER_BYTES
    with capsys.disabled():
        print(
            f"\n[mapformat] text_cylinder: {d['point_count']} points, {d['layer_count']} layers, "
            f"{len(data)} bytes = {bpp:.2f} bytes/point (fixed overhead {framing} bytes)"
        )
    assert d["point_count"] > 300 and bpp < 3.5
    # q = 100 um halves most deltas: the same text fits in fewer bytes.
    m = mf.decode_map(data)
    mm = [(layer.z_cmm / 100, m.points_mm(layer)) for layer in m.layers]
    coarse = mf.encode_map(mm, quantum_um=100)
    assert len(coarse) < len(data)


def test_record_bytes_are_the_records_encoded_again():
    """record_bytes cuts the layer records out of a map's bytes (annotate's way) rather than
    encoding the decoded layers again: the same bytes, on every valid vector map (weights,
    extremes, a full layer) and on random ones with weights, many-byte varints and negative
    points."""
    import random
    vectors = Path(__file__).resolve().parents[3] / "test" / "vectors"
    maps = [p.read_bytes() for p in sorted(vectors.glob("*.bkm")) if not p.name.startswith("bad_")]
    rng = random.Random(26)
    for w in (False, True):
        layers = [(0.3 * (k + 1), [(rng.uniform(-1500, 1500), rng.uniform(-1500, 1500))
                                   for _ in range(rng.randint(1, 64))]) for k in range(40)]
        weights = [[rng.randint(0, 255) for _ in pts] for _, pts in layers] if w else None
        maps.append(mf.encode_map(layers, weights=weights))
    assert len(maps) >= 7
    for m in maps:
        bm = mf.decode_map(m)
        assert mf.record_bytes(m) == [
            mf.encode_record(l, bm.has_weights) for l in bm.layers]
