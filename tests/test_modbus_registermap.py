"""Register map CSV: errors with file:line and column, coalescing, numpy decode/encode."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from connectors.registermap import (
    MAX_BITS,
    MAX_REGISTERS,
    RegisterMap,
    RegisterMapError,
    encode,
    pack_bits,
    unpack_bits,
)

HEADER = "tag,table,address,type,word_order,scale,offset,unit\n"


def test_parse_defaults_and_roundtrip(tmp_path):
    p = tmp_path / "plc.csv"
    p.write_text(
        "# a comment line\n"
        + HEADER
        + "F,ir,0,float32,ABCD,1,0,t/h\n\nCV,hr,10,int16,,0.01,,%\nA3,hr,20.3,bool,,,,\n"
    )
    m = RegisterMap.from_csv(p)
    assert m.names == ["F", "CV", "A3"]
    assert m["CV"].word_order == "ABCD" and m["CV"].scale == 0.01 and m["CV"].offset == 0
    assert m["A3"].bit == 3 and m["A3"].address == 20
    assert m["CV"].line == 5
    assert RegisterMap.parse(m.to_csv()).tags[0].tag == "F"
    assert [(t.tag, t.address, t.bit) for t in RegisterMap.parse(m.to_csv()).tags] == [
        (t.tag, t.address, t.bit) for t in m.tags
    ]


@pytest.mark.parametrize(
    ("text", "where", "column"),
    [
        ("tag,table,address\nF,ir,0\n", ":1:", "'type'"),
        (HEADER + "F,ir,0,flaot32,ABCD,1,0,\n", ":2:", "'type'"),
        (HEADER + "F,xx,0,float32,ABCD,1,0,\n", ":2:", "'table'"),
        (HEADER + "F,ir,zero,float32,ABCD,1,0,\n", ":2:", "'address'"),
        (HEADER + "F,ir,0,float32,BADC,1,0,\n", ":2:", "'word_order'"),
        (HEADER + "F,ir,0,float32,ABCD,x,0,\n", ":2:", "'scale'"),
        (HEADER + "F,ir,0,float32,ABCD,0,0,\n", ":2:", "'scale'"),
        (HEADER + "F,co,0,float32,ABCD,1,0,\n", ":2:", "'type'"),
        (HEADER + "F,hr,0,bool,,,,\n", ":2:", "'address'"),
        (HEADER + "F,ir,0,float32,,,,\nG,ir,1,int16,,,,\n", ":3:", "'address'"),
        (HEADER + "F,ir,0,float32,,,,\n\nF,ir,4,int16,,,,\n", ":4:", "'tag'"),
        (HEADER + "A,hr,5.2,bool,,,,\nB,hr,5.2,bool,,,,\n", ":3:", "'address'"),
        (HEADER + "F,ir,0,float32,,,,,extra\n", ":2:", "column"),
    ],
)
def test_errors_name_file_line_and_column(text, where, column):
    with pytest.raises(RegisterMapError) as e:
        RegisterMap.parse(text, source="plc.csv")
    msg = str(e.value)
    assert msg.startswith("plc.csv" + where), msg
    assert column in msg, msg


def test_bits_of_one_status_word_may_share_a_register():
    m = RegisterMap.parse(HEADER + "A,hr,5.2,bool,,,,\nB,hr,5.3,bool,,,,\nW,hr,6,uint16,,,,\n")
    (block,) = m.plan().blocks
    assert (block.table, block.start, block.count) == ("hr", 5, 2)


def test_coalescing_limits_and_gaps():
    rows = "".join(f"T{i},hr,{2 * i},float32,,,,\n" for i in range(200))
    rows += "".join(f"C{i},co,{i},bool,,,,\n" for i in range(4500))
    rows += "L,hr,1000,int16,,,,\nM,hr,1003,int16,,,,\n"
    m = RegisterMap.parse(HEADER + rows)
    plan = m.plan()
    hr = [b for b in plan.blocks if b.table == "hr"]
    co = [b for b in plan.blocks if b.table == "co"]
    assert all(b.count <= MAX_REGISTERS for b in hr)
    assert [b.count for b in hr[:4]] == [124, 124, 124, 28]  # floats never split
    assert [b.count for b in co] == [MAX_BITS, MAX_BITS, 500]
    assert [(b.start, b.count) for b in hr[4:]] == [(1000, 1), (1003, 1)]  # gap of 2
    near = [b for b in m.plan(max_gap=2).blocks if b.table == "hr"][4:]
    assert [(b.start, b.count) for b in near] == [(1000, 4)]
    assert sum(len(b.tags) for b in plan.blocks) == len(m)


def test_decode_matches_pymodbus_convert_from_registers():
    """Our numpy decode against pymodbus's own converter, both word orders, random data."""
    from pymodbus.client import AsyncModbusTcpClient as C

    rng = np.random.default_rng(1)
    n = 64
    rows = []
    for i in range(n):
        typ = ["float32", "int32", "int16", "uint16"][i % 4]
        wo = "CDAB" if i % 8 >= 4 else "ABCD"
        rows.append(f"T{i},hr,{2 * i},{typ},{wo},,,\n")
    m = RegisterMap.parse(HEADER + "".join(rows))
    plan = m.plan()
    words = rng.integers(0, 65536, size=2 * n).astype(np.uint16)
    words[0::4] = rng.integers(0x3000, 0x4F00, size=len(words[0::4]))  # finite floats
    buf = plan.new_buffer()
    for b in plan.blocks:
        buf[b.buf_offset : b.buf_offset + b.count] = words[b.start : b.start + b.count]
    got = plan.decode(buf)
    dt = C.DATATYPE
    for i, t in enumerate(m.tags):
        regs = [int(w) for w in words[t.address : t.address + t.width]]
        kind = {"float32": dt.FLOAT32, "int32": dt.INT32, "int16": dt.INT16, "uint16": dt.UINT16}
        order = "little" if t.word_order == "CDAB" else "big"
        want = C.convert_from_registers(regs, kind[t.type], word_order=order)
        assert got[i] == pytest.approx(float(want), rel=1e-7), t


def test_encode_is_the_inverse_and_matches_struct():
    m = RegisterMap.parse(
        HEADER
        + "F,hr,0,float32,ABCD,1,0,\nG,hr,2,float32,CDAB,2,1,\nS,hr,4,int16,,0.1,0,\n"
        + "I,hr,5,int32,CDAB,,,\nU,hr,7,uint16,,0.01,-50,\nB,hr,8.15,bool,,,,\nK,co,0,bool,,,,\n"
    )
    hi, lo = struct.unpack(">HH", struct.pack(">f", 1.5))
    assert encode(m["F"], 1.5) == [hi, lo]
    hi, lo = struct.unpack(">HH", struct.pack(">f", (-3.25 - 1) / 2))
    assert encode(m["G"], -3.25) == [lo, hi]
    assert encode(m["S"], -123.4) == [struct.unpack(">H", struct.pack(">h", -1234))[0]]
    assert encode(m["B"], 1, current=0x0001) == [0x8001]
    assert encode(m["B"], 0, current=0x8001) == [0x0001]
    assert encode(m["K"], 1) == [True]
    with pytest.raises(ValueError, match="outside the range"):
        encode(m["S"], 5000.0)
    plan = m.plan()
    vals = np.array([1.5, -3.25, -123.4, -70000, 25.0, 1, 1])
    np.testing.assert_allclose(plan.decode(plan.encode(vals)), vals, rtol=1e-6)


def test_bit_packed_words_lsb_first():
    bits = unpack_bits([0x0001, 0x8000, 0x00A5])
    assert bits.shape == (3, 16)
    assert bits[0, 0] and not bits[0, 1:].any()
    assert bits[1, 15] and not bits[1, :15].any()
    assert list(np.flatnonzero(bits[2])) == [0, 2, 5, 7]
    assert pack_bits(bits[2]) == 0x00A5


def test_docs_example_and_default_layouts_match_the_code():
    """docs/reference/connectors.md: the example map parses; the documented addresses are
    the code's."""
    import re
    from pathlib import Path

    from connectors.modbus_server import (
        PLANT_TAGS,
        UnitLayout,
        default_output_map,
        default_plant_map,
    )

    doc = (Path(__file__).resolve().parents[1] / "docs" / "reference" / "connectors.md").read_text()
    (example,) = re.findall(r"```csv\n(.*?)```", doc, flags=re.S)
    m = RegisterMap.parse(example, source="docs/reference/connectors.md")
    assert m["TRIP"].bit == 15 and m["X"].word_order == "CDAB"
    plant = default_plant_map()
    assert [(t.tag, t.table, t.address, t.type) for t in plant.tags] == [
        (tag, "ir", 2 * i, "float32") for i, tag in enumerate(PLANT_TAGS)
    ]
    out = default_output_map(
        [UnitLayout("A", ["f1"], ["r1"]), UnitLayout("B", ["f1", "f2"], ["r1"], ["M"])]
    )
    where = {t.tag: (t.table, t.address, t.type) for t in out.tags}
    assert where["B.status"] == ("hr", 100, "uint16")
    assert where["B.quality"] == ("hr", 101, "uint16")
    assert where["B.faults"] == ("hr", 102, "uint16")
    assert where["B.alarm"] == ("hr", 103, "uint16")
    assert where["B.updates"] == ("hr", 104, "uint16")
    assert where["B.time"] == ("hr", 106, "int32")
    assert where["B.certainty.f2"] == ("hr", 112, "float32")
    assert where["B.residual.r1"] == ("hr", 150, "float32")
    assert where["B.coverage.M"] == ("hr", 190, "float32")
    assert where["B.ack"] == ("co", 100, "bool")
    assert where["B.fault.f2"] == ("co", 102, "bool")
