"""Compact bulge map v1: encoder, decoder and M721 upload lines.

Byte-compatible with the firmware codec (src/bulge_map.cpp); the layout is
specified in docs/reference/map-format.md. Pure standard library.

Units: the public encoder takes millimetres; the map stores XY in quanta of
``quantum_um`` micrometres (int16) and z in 0.01 mm (uint16). Values are
rounded half away from zero to those grids; anything that then leaves the
format's ranges raises a :class:`MapFormatError` subclass (a ``ValueError``),
never wraps or clips.

Example::

    data = encode_map([(0.3, [(10.0, 0.0), (9.8, 2.0)])])
    for line in upload_lines(data, start_line=1):
        send(line)
"""

from __future__ import annotations

import base64
import binascii
import math
import zlib
from dataclasses import dataclass, field
from typing import Iterable, Sequence

MAGIC = b"BKM"
VERSION = 1
FLAG_WEIGHTS = 0x01
HEADER_BYTES = 8
# the firmware's BK_MAP_ARENA_BYTES: layer records it holds at once (header kept beside)
ARENA_BYTES = 1024
LAYER_POINTS_MAX = 64  # the firmware's BK_LAYER_POINTS_MAX; the host refuses more
VARINT_MAX_BYTES = 3
VARINT_LIMIT = 1 << 21
INT16_MIN, INT16_MAX = -32768, 32767
Z_CMM_MAX = 0xFFFF
QUANTUM_UM_DEFAULT = 50
MAP_BYTES_MAX = 0xFFFF  # M721 S is a uint16 on the firmware
CHUNK_BYTES = 40  # 64 base32 characters per M721 line
LINE_MAX = 95  # Marlin's 96-byte command buffer, NUL excluded


# ---- errors --------------------------------------------------------------------------
class MapFormatError(ValueError):
    """Base class. ``code`` matches the firmware's MapError name (MAP_ERR_<CODE>)."""

    code = "input"

    def __init__(self, message: str, offset: int | None = None, source: str | None = None):
        self.offset = offset
        self.source = source
        where = []
        if source:
            where.append(source)
        if offset is not None:
            where.append(f"byte {offset}")
        super().__init__(": ".join(where + [message]))


class MapTruncatedError(MapFormatError):
    code = "truncated"


class BadMagicError(MapFormatError):
    code = "magic"


class BadVersionError(MapFormatError):
    code = "version"


class BadFlagsError(MapFormatError):
    code = "flags"


class HeaderValueError(MapFormatError):
    code = "header_value"


class HeaderCRCError(MapFormatError):
    code = "header_crc"


class RecordCRCError(MapFormatError):
    code = "record_crc"


class VarintError(MapFormatError):
    code = "varint"


class CountZeroError(MapFormatError):
    code = "count_zero"


class CountMaxError(MapFormatError):
    code = "count_max"


class LengthError(MapFormatError):
    code = "length"


class CoordinateError(MapFormatError):
    code = "coord"


class ZOrderError(MapFormatError):
    code = "z_order"


class MapTooLargeError(MapFormatError):
    code = "too_large"


# ---- model ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Layer:
    """One layer record in format units: z in 0.01 mm, points in quanta."""

    z_cmm: int
    points: tuple[tuple[int, int], ...]
    weights: tuple[int, ...] | None = None  # 0..255 per point, or None


@dataclass
class BulgeMap:
    quantum_um: int = QUANTUM_UM_DEFAULT
    layer_height_cmm: int = 30
    has_weights: bool = False
    layers: list[Layer] = field(default_factory=list)
    version: int = VERSION

    @property
    def flags(self) -> int:
        return FLAG_WEIGHTS if self.has_weights else 0

    @property
    def layer_height_mm(self) -> float:
        return self.layer_height_cmm / 100.0

    @property
    def point_count(self) -> int:
        return sum(len(layer.points) for layer in self.layers)

    def points_mm(self, layer: Layer) -> list[tuple[float, float]]:
        q = self.quantum_um / 1000.0
        return [(x * q, y * q) for x, y in layer.points]


# ---- primitives ----------------------------------------------------------------------
def _crc8_table() -> bytes:
    table = bytearray(256)
    for i in range(256):
        c = i
        for _ in range(8):
            c = ((c << 1) ^ 0x07) & 0xFF if c & 0x80 else (c << 1) & 0xFF
        table[i] = c
    return bytes(table)


_CRC8 = _crc8_table()


def crc8(data: bytes, crc: int = 0) -> int:
    """CRC-8, poly 0x07, init 0, no reflection, no xorout."""
    for b in data:
        crc = _CRC8[crc ^ b]
    return crc


def crc32(data: bytes) -> int:
    """IEEE CRC-32 (zlib), as M721 C carries it."""
    return zlib.crc32(data) & 0xFFFFFFFF


def zigzag(v: int) -> int:
    """zz(v) = (v << 1) ^ (v >> 31) for an int32 v; non-negative result."""
    if not -(1 << 31) <= v < (1 << 31):
        raise MapFormatError(f"zigzag input {v} outside int32")
    return (v << 1) ^ (v >> 31)


def unzigzag(u: int) -> int:
    return (u >> 1) ^ -(u & 1)


def varint(v: int) -> bytes:
    """Unsigned LEB128, at most 3 bytes."""
    if not 0 <= v < VARINT_LIMIT:
        raise MapFormatError(f"varint value {v} outside 0..{VARINT_LIMIT - 1}")
    out = bytearray()
    while v >= 0x80:
        out.append((v & 0x7F) | 0x80)
        v >>= 7
    out.append(v)
    return bytes(out)


def _read_varint(data: bytes, pos: int, end: int) -> tuple[int, int] | None | str:
    """(value, new_pos); None when data ends first; "bad" when over-long."""
    v = 0
    for i in range(VARINT_MAX_BYTES):
        if pos + i >= end:
            return None
        b = data[pos + i]
        v |= (b & 0x7F) << (7 * i)
        if not b & 0x80:
            if i and b == 0:
                return "bad"  # not minimally encoded
            return v, pos + i + 1
    return "bad"


def round_half_away(v: float) -> int:
    return int(math.copysign(math.floor(abs(v) + 0.5), v))


# ---- encoder -------------------------------------------------------------------------
def encode_header(quantum_um: int, layer_height_cmm: int, has_weights: bool) -> bytes:
    if not 1 <= quantum_um <= 255:
        raise HeaderValueError(f"quantum {quantum_um} um outside 1..255")
    if not 1 <= layer_height_cmm <= 255:
        raise HeaderValueError(f"layer height {layer_height_cmm / 100:.2f} mm outside 0.01..2.55")
    head = MAGIC + bytes([VERSION, FLAG_WEIGHTS if has_weights else 0, quantum_um, layer_height_cmm])
    return head + bytes([crc8(head)])


def encode_record(layer: Layer, has_weights: bool, max_points: int = LAYER_POINTS_MAX) -> bytes:
    """One layer record (z, n, len, body, CRC-8) from format units."""
    where = f"layer z {layer.z_cmm / 100:.2f} mm"
    n = len(layer.points)
    if not 0 <= layer.z_cmm <= Z_CMM_MAX:
        raise ZOrderError(f"{where}: z outside 0..655.35 mm")
    if n == 0:
        raise CountZeroError(f"{where}: no points")
    if n > max_points:
        raise CountMaxError(f"{where}: {n} points, at most {max_points}")
    body = bytearray()
    px = py = 0
    for i, (x, y) in enumerate(layer.points):
        if not (INT16_MIN <= x <= INT16_MAX and INT16_MIN <= y <= INT16_MAX):
            raise CoordinateError(f"{where}: point {i} ({x}, {y}) quanta outside int16")
        body += varint(zigzag(x - px)) + varint(zigzag(y - py))
        px, py = x, y
    if has_weights:
        if layer.weights is None or len(layer.weights) != n:
            raise MapFormatError(f"{where}: needs {n} weights")
        for w in layer.weights:
            if not isinstance(w, int) or not 0 <= w <= 255:
                raise MapFormatError(f"{where}: weight {w!r} is not an integer 0..255")
        body += bytes(layer.weights)
    elif layer.weights is not None:
        raise MapFormatError(f"{where}: weights given but the map has none")
    rec = layer.z_cmm.to_bytes(2, "little") + varint(n) + varint(len(body)) + bytes(body)
    return rec + bytes([crc8(rec)])


def encode_layers_q(layers: Iterable[Layer], has_weights: bool, after_z_cmm: int = -1) -> bytes:
    out = bytearray()
    prev = after_z_cmm
    for layer in layers:
        if layer.z_cmm <= prev:
            raise ZOrderError(
                f"layer z {layer.z_cmm / 100:.2f} mm does not follow z {prev / 100:.2f} mm (z must increase)"
            )
        prev = layer.z_cmm
        out += encode_record(layer, has_weights)
    return bytes(out)


def encode_map_q(m: BulgeMap) -> bytes:
    """A full image from format units."""
    data = encode_header(m.quantum_um, m.layer_height_cmm, m.has_weights) + encode_layers_q(m.layers, m.has_weights)
    if len(data) > MAP_BYTES_MAX:
        raise MapTooLargeError(f"map of {len(data)} bytes exceeds {MAP_BYTES_MAX}")
    return data


def _layer_height_cmm(layer_height_mm: float) -> int:
    cmm = round_half_away(layer_height_mm * 100)
    if abs(cmm - layer_height_mm * 100) > 1e-6:
        raise HeaderValueError(f"layer height {layer_height_mm} mm is not a multiple of 0.01 mm")
    return cmm


def _quantize_layers(layers, quantum_um: int, weights) -> list[Layer]:
    if not 1 <= quantum_um <= 255:
        raise HeaderValueError(f"quantum {quantum_um} um outside 1..255")
    layers = list(layers)
    if weights is not None:
        weights = list(weights)
        if len(weights) != len(layers):
            raise MapFormatError(f"{len(weights)} weight lists for {len(layers)} layers")
    out = []
    scale = 1000.0 / quantum_um
    for i, (z_mm, pts) in enumerate(layers):
        z = round_half_away(z_mm * 100)
        q = []
        for j, (x, y) in enumerate(pts):
            if not (math.isfinite(x) and math.isfinite(y)):
                raise CoordinateError(f"layer {i} (z {z_mm} mm): point {j} is not finite")
            q.append((round_half_away(x * scale), round_half_away(y * scale)))
        w = tuple(weights[i]) if weights is not None else None
        out.append(Layer(z, tuple(q), w))
    return out


def encode_map(
    layers: Iterable[tuple[float, Sequence[tuple[float, float]]]],
    quantum_um: int = QUANTUM_UM_DEFAULT,
    layer_height_mm: float = 0.3,
    weights: Sequence[Sequence[int]] | None = None,
) -> bytes:
    """Encode a map from millimetres.

    layers: (z_mm, [(x_mm, y_mm), ...]) in increasing z, points in wall order.
    weights: None, or per layer a list of dwell weights 0..255 (255 = full dwell).
    """
    lh = _layer_height_cmm(layer_height_mm)
    q = _quantize_layers(layers, quantum_um, weights)
    return encode_map_q(BulgeMap(quantum_um, lh, weights is not None, q))


def encode_records(
    layers: Iterable[tuple[float, Sequence[tuple[float, float]]]],
    quantum_um: int = QUANTUM_UM_DEFAULT,
    weights: Sequence[Sequence[int]] | None = None,
    after_z_mm: float | None = None,
) -> bytes:
    """Layer records (no header) for an M721 A1 append.

    quantum_um and the presence of weights must match the map in force;
    after_z_mm (the last z already sent) lets the host check the z order.
    """
    after = -1 if after_z_mm is None else round_half_away(after_z_mm * 100)
    return encode_layers_q(_quantize_layers(layers, quantum_um, weights), weights is not None, after)


# ---- decoder -------------------------------------------------------------------------
def _decode_records(data: bytes, pos: int, has_weights: bool, after_z: int, source, max_points) -> list[Layer]:
    # Check order mirrors src/bulge_map.cpp so both sides name the same error.
    layers = []
    end = len(data)
    prev = after_z
    while pos < end:
        start = pos

        def fail(cls, msg):
            raise cls(f"record: {msg}", start, source)

        def varint(at, what):
            r = _read_varint(data, at, end)
            if r is None:
                fail(MapTruncatedError, f"data ends inside {what}")
            if r == "bad":
                fail(VarintError, f"over-long varint {what}")
            return r

        if end - pos < 2:
            fail(MapTruncatedError, "data ends inside z")
        z = data[pos] | data[pos + 1] << 8
        pos += 2
        n, pos = varint(pos, "n")
        if n == 0:
            fail(CountZeroError, f"z {z / 100:.2f} mm has 0 points")
        if n > max_points:
            fail(CountMaxError, f"z {z / 100:.2f} mm has {n} points, at most {max_points}")
        blen, pos = varint(pos, "len")
        if blen + 1 > end - pos:
            fail(MapTruncatedError, f"body of {blen} bytes + CRC runs past the end ({end - pos} left)")
        body_end = pos + blen
        if crc8(data[start:body_end]) != data[body_end]:
            fail(RecordCRCError, f"CRC mismatch (z {z / 100:.2f} mm)")
        pts = []
        x = y = 0
        for i in range(n):
            for axis in range(2):
                r = _read_varint(data, pos, body_end)
                if r is None:
                    fail(LengthError, f"len {blen} ends before point {i} of {n}")
                if r == "bad":
                    fail(VarintError, f"over-long varint in point {i}")
                u, pos = r
                if axis == 0:
                    x += unzigzag(u)
                else:
                    y += unzigzag(u)
            if not (INT16_MIN <= x <= INT16_MAX and INT16_MIN <= y <= INT16_MAX):
                fail(CoordinateError, f"point {i} ({x}, {y}) leaves int16")
            pts.append((x, y))
        w = None
        if has_weights:
            if body_end - pos < n:
                fail(LengthError, f"len {blen} leaves no room for {n} weights")
            w = tuple(data[pos : pos + n])
            pos += n
        if pos != body_end:
            fail(LengthError, f"len {blen} but the body needs {blen - (body_end - pos)}")
        if z <= prev:
            fail(ZOrderError, f"z {z / 100:.2f} mm does not exceed {prev / 100:.2f} mm")
        prev = z
        layers.append(Layer(z, tuple(pts), w))
        pos = body_end + 1
    return layers


def decode_map(data: bytes, source: str | None = None, max_points: int = LAYER_POINTS_MAX) -> BulgeMap:
    """Parse and fully validate a map image; raises a MapFormatError subclass."""
    data = bytes(data)
    if len(data) < HEADER_BYTES:
        raise MapTruncatedError(f"header needs {HEADER_BYTES} bytes, got {len(data)}", 0, source)
    if data[:3] != MAGIC:
        raise BadMagicError(f"magic {data[:3]!r}, expected b'BKM'", 0, source)
    if crc8(data[:7]) != data[7]:
        raise HeaderCRCError(f"header CRC {data[7]:#04x}, computed {crc8(data[:7]):#04x}", 7, source)
    if data[3] != VERSION:
        raise BadVersionError(f"version {data[3]}, this decoder reads {VERSION}", 3, source)
    if data[4] & ~FLAG_WEIGHTS & 0xFF:
        raise BadFlagsError(f"unknown flag bits {data[4]:#04x}", 4, source)
    if data[5] == 0 or data[6] == 0:
        raise HeaderValueError("quantum and layer height must be non-zero", 5, source)
    has_w = bool(data[4] & FLAG_WEIGHTS)
    layers = _decode_records(data, HEADER_BYTES, has_w, -1, source, max_points)
    return BulgeMap(data[5], data[6], has_w, layers, data[3])


def record_bytes(map_bytes: bytes) -> list[bytes]:
    """The layer records of a map image decode_map has accepted, each as its bytes there:
    decode_map takes only the one encoding encode_record writes (minimal varints, exact
    lengths, CRCs checked), so they are its layers encoded again, without the work."""
    recs = []
    pos, end = HEADER_BYTES, len(map_bytes)
    while pos < end:
        start = pos
        _, pos = _read_varint(map_bytes, pos + 2, end)       # past z and n
        body, pos = _read_varint(map_bytes, pos, end)
        pos += body + 1                                      # and the CRC
        recs.append(bytes(map_bytes[start:pos]))
    return recs


def decode_records(
    data: bytes,
    has_weights: bool,
    after_z_cmm: int = -1,
    source: str | None = None,
    max_points: int = LAYER_POINTS_MAX,
) -> list[Layer]:
    """Parse and validate appended records (no header)."""
    return _decode_records(bytes(data), 0, has_weights, after_z_cmm, source, max_points)


def bytes_per_point(data: bytes) -> float:
    """Average bytes per bulge point of an image, header and record framing included."""
    m = decode_map(data)
    return len(data) / m.point_count if m.point_count else float("inf")


# ---- M721 ----------------------------------------------------------------------------
def line_checksum(text: str) -> int:
    """Marlin/RepRap checksum: XOR of every byte before '*'."""
    cs = 0
    for b in text.encode("ascii"):
        cs ^= b
    return cs


def b32(data: bytes) -> str:
    return base64.b32encode(data).decode("ascii").rstrip("=")


def check_upload_fits(data: bytes, arena: int = ARENA_BYTES, source: str = "map") -> None:
    """A whole-map upload (M721 S.. then E) must fit the printer's arena, or
    the firmware refuses it at commit; only `annotate` can stream the rest."""
    need = len(data) - HEADER_BYTES
    if need > arena:
        raise MapFormatError(
            f"{source}: the map's layer records need {need} bytes but the printer's arena holds "
            f"{arena}: uploaded at once the printer would refuse it (M721 E). Use `bulgekit "
            "annotate GCODE MAP`, which uploads what fits and streams the other layers as "
            "appends while printing.")


def upload_lines(
    data: bytes,
    append: bool = False,
    start_line: int | None = None,
    *,
    has_weights: bool | None = None,
    chunk_bytes: int = CHUNK_BYTES,
    checked: bool = False,
) -> list[str]:
    """The M721 lines that upload data: begin, chunks, commit.

    append=False: data is a full image (validated here). append=True: data is
    layer records for "M721 A1"; they are validated too, with has_weights as
    the map in force has it (None: accepted if either reading is valid).
    checked: data is a valid image or records already (cut from a decoded map): not decoded again.
    start_line: number the lines N<start_line>.. and add "*<checksum>".
    """
    data = bytes(data)
    if not data:
        raise MapFormatError("nothing to upload")
    if len(data) > MAP_BYTES_MAX:
        raise MapTooLargeError(f"{len(data)} bytes exceed the M721 limit of {MAP_BYTES_MAX}")
    if not 1 <= chunk_bytes <= CHUNK_BYTES or chunk_bytes % 5:
        raise MapFormatError(f"chunk_bytes {chunk_bytes} must be a multiple of 5 within 5..{CHUNK_BYTES}")
    if append and not checked:
        choices = [has_weights] if has_weights is not None else [False, True]
        errors = []
        for w in choices:
            try:
                decode_records(data, w, source="append records")
                break
            except MapFormatError as e:
                errors.append(e)
        else:
            raise errors[0]
    elif not checked:
        decode_map(data, source="map")
    cmds = [f"M721 S{len(data)} C{crc32(data)}" + (" A1" if append else "")]
    for off in range(0, len(data), chunk_bytes):
        cmds.append(f"M721 O{off} D{b32(data[off:off + chunk_bytes])}")
    cmds.append("M721 E")
    if start_line is None:
        lines = cmds
    else:
        if start_line < 0:
            raise MapFormatError(f"start_line {start_line} is negative")
        lines = []
        for i, cmd in enumerate(cmds):
            text = f"N{start_line + i} {cmd}"
            lines.append(f"{text}*{line_checksum(text)}")
    for line in lines:
        if len(line) > LINE_MAX:
            raise MapFormatError(f"line of {len(line)} chars exceeds {LINE_MAX}: {line[:24]}...")
    return lines


def read_upload(lines: Iterable[tuple[int, str]], source: str = "<gcode>",
                refused: list | None = None) -> BulgeMap | None:
    """The map a G-code file's M721 lines put in force, as the firmware's MapUpload takes them
    (docs/reference/mcodes.md, M721): (line number, code) pairs, the code without comment or checksum
    (an N word may lead). A begin (S, C; A1: an append), its chunks (O, D) and the commit (E):
    a full map replaces the one in force, an append's records go after it; X clears it.
    Returns every layer the file uploads over the print, its appends included (what the
    firmware holds layer by layer as it prints), or None when nothing was committed. A
    malformed line, a CRC or structure failure, or a second, different map after the first:
    MapFormatError naming the line; with `refused` (a list) the firmware's way instead: the
    message goes there and the map in force stays as it was."""
    m: BulgeMap | None = None
    up = None                                   # (size, crc, append, bytearray, received ranges)
    for no, code in lines:
        where = f"{source}:{no}"
        words = {}
        for tok in code.split()[1:]:
            if tok[:1].upper() == "N" and not words and tok[1:].isdigit():
                continue
            words[tok[:1].upper()] = tok[1:]
        try:
            if {"S", "C", "A"} & words.keys():
                up = (int(words["S"]), int(words["C"]), words.get("A", "0") in ("", "1"),
                      bytearray(int(words["S"])), [])
            elif "O" in words:
                if up is None:
                    raise MapFormatError(f"{where}: M721 chunk without a begin")
                off = int(words["O"])
                d = words["D"].upper()
                chunk = base64.b32decode(d + "=" * (-len(d) % 8))
                if off + len(chunk) > len(up[3]):
                    raise MapFormatError(f"{where}: M721 O{off}+{len(chunk)} > S{len(up[3])}")
                up[3][off:off + len(chunk)] = chunk
                up[4].append((off, off + len(chunk)))
            elif "E" in words:
                if up is None:
                    raise MapFormatError(f"{where}: M721 E without a begin")
                size, crc, append, data, got = up
                end = 0
                for a, b in sorted(got):
                    if a > end:
                        break
                    end = max(end, b)
                if end < size:                  # the upload stays open for the missing chunks
                    raise MapFormatError(f"{where}: M721 E after {end} of {size} bytes")
                up = None
                if crc32(bytes(data)) != crc:
                    raise MapFormatError(f"{where}: M721 CRC {crc32(bytes(data))} != C{crc}")
                if not append:
                    new = decode_map(bytes(data), source=where)
                    if m is not None and m.layers and new.layers != m.layers[:len(new.layers)]:
                        raise MapFormatError(f"{where}: a second map in one file (not modelled)")
                    if m is None or not m.layers:
                        m = new
                elif m is None:
                    raise MapFormatError(f"{where}: M721 A1 append without a map")
                else:
                    after = m.layers[-1].z_cmm if m.layers else -1
                    m.layers += decode_records(bytes(data), m.has_weights, after, where)
            # X (clear) and a bare M721 (status) change nothing the print's stops need: the
            # annotator clears before its upload and after the print
        except (KeyError, ValueError, binascii.Error) as e:
            if not isinstance(e, MapFormatError):
                e = MapFormatError(f"{where}: malformed M721 line {code.strip()!r}")
            if refused is None:
                raise e from None
            refused.append(str(e))
    return m
