"""Checkpoint encoding: exact round trips, float32 only where exact, bounded inflation, shared feature tables."""
import base64
import json
import lzma
import zlib

import numpy as np
import pytest

from ftorch.checkpoint import MAX_BYTES, ROWS, decode_array, decode_text, encode_array, encode_text, load_checkpoint
from ftorch.errors import InputError
from ftorch.space.features import CHUNK, Conjunction, FeatureTable, Geometric, Part, Texel, unpack_features


def test_arrays_round_trip_exactly_in_float32_where_that_is_exact():
    values = np.random.default_rng(0).random((30, 7)).astype(np.float32).astype(np.float64)
    values[3, 2] = np.nan
    packed = encode_array(values)
    assert packed["dtype"] == "<f4"
    assert np.array_equal(decode_array(packed), values, equal_nan=True)
    wide = values + 1e-12  # not float32 numbers: kept as float64
    assert encode_array(wide)["dtype"] == "<f8" and np.array_equal(decode_array(encode_array(wide)), wide, equal_nan=True)


def test_an_array_written_relative_to_one_the_reader_holds_restores_exactly_and_shrinks():
    rng = np.random.default_rng(1)
    reference = rng.random((300, 40)).astype(np.float32).astype(np.float64)
    reference[::7, 3] = np.nan
    values = reference.copy()
    values[9, 4], values[0, 3], values[1, 1:3] = np.nan, 0.25, np.nan  # where the two differ, NaN either side
    for array in (values, values + np.eye(300, 40) * 1e-12):  # float32 numbers, and float64 ones
        packed = encode_array(array, reference)
        assert packed["relative"] and packed["dtype"] == encode_array(array)["dtype"]
        assert np.array_equal(decode_array(packed, reference), array, equal_nan=True)
        assert len(json.dumps(packed)) < len(json.dumps(encode_array(array))) / 10
    for scalar in (np.array(0.5), np.zeros((0, 3))):
        assert np.array_equal(decode_array(encode_array(scalar, scalar + 1), scalar + 1), scalar)
    packed = encode_array(values, reference)
    with pytest.raises(ValueError, match="relative to values that are not given"):
        decode_array(packed)
    with pytest.raises(ValueError, match="a reference of shape"):
        decode_array(packed, reference[1:])
    with pytest.raises(ValueError, match="relative to values that are not given"):
        decode_array({**packed, "relative": "yes"}, reference)


def test_large_arrays_go_in_blocks_and_empty_ones_round_trip():
    values = np.arange(3 * ROWS * 2, dtype=np.float64).reshape(3 * ROWS, 2)[: 2 * ROWS + 5]
    packed = encode_array(values)
    assert len(packed["blocks"]) == 3 and np.array_equal(decode_array(packed), values)
    for empty in (np.zeros((0, 4)), np.zeros((5, 0)), np.zeros(0), np.array(2.5)):
        assert np.array_equal(decode_array(encode_array(empty)), empty)


def test_inflation_stops_at_the_declared_size():
    bomb = {"shape": [4], "dtype": "<f8", "blocks": [base64.b64encode(zlib.compress(bytes(10**7))).decode()]}
    with pytest.raises(ValueError, match="other than the 32 bytes"):
        decode_array(bomb)
    with pytest.raises(ValueError, match="more than the"):
        decode_array({"shape": [MAX_BYTES, 1], "dtype": "<f8", "blocks": bomb["blocks"] * (MAX_BYTES // ROWS)})
    with pytest.raises(ValueError, match="negative shape"):
        decode_array({"shape": [-1, 4], "dtype": "<f8", "blocks": bomb["blocks"]})
    with pytest.raises(ValueError, match="2 blocks for 4 rows"):
        decode_array({"shape": [4], "dtype": "<f8", "blocks": bomb["blocks"] * 2})
    with pytest.raises(ValueError, match="damaged array"):
        decode_array({"shape": [4], "dtype": "object", "blocks": bomb["blocks"]})
    text = encode_text("features " * 1000)
    assert decode_text(text) == "features " * 1000
    with pytest.raises(ValueError, match="damaged text"):
        decode_text({"bytes": 10, "data": text["data"]})


def test_texts_are_xz_blocks_and_version_2_zlib_texts_still_read():
    text = json.dumps([{"type": "texel", "vector": [0.1 * i] * 15} for i in range(200)])
    packed = encode_text(text)
    assert base64.b64decode(packed["data"]).startswith(b"\xfd7zXZ\x00") and decode_text(packed) == text
    raw = text.encode()
    old = {"bytes": len(raw), "data": base64.b64encode(zlib.compress(raw, 6)).decode()}  # as version 2 wrote it
    assert decode_text(old) == text and len(packed["data"]) < len(old["data"])
    for damaged in (lzma.compress(raw, preset=1) + b"tail", lzma.compress(raw, preset=1)[:-20],
                    lzma.compress(bytes(10**7), preset=1)):  # data after the stream, a cut stream, a bomb
        with pytest.raises(ValueError, match="damaged text"):
            decode_text({"bytes": len(raw), "data": base64.b64encode(damaged).decode()})


def test_feature_tables_store_each_feature_once_and_read_back_equal():
    texel = Texel([0.1 * (i + 1) for i in range(15)])
    pair = Geometric((Part("edgel", [1.0, 0.0]), Part("edgel", [0.5, 0.25], phi=0.3, dtheta=1.1, d=2.0, dsigma=1.4)))
    table = FeatureTable()
    assert [table.index(f) for f in (texel, pair, texel, Conjunction(texel, pair), pair)] == [0, 1, 0, 2, 1]
    assert unpack_features(table.pack()) == [texel, pair, Conjunction(texel, pair)]


def test_deeply_nested_or_foreign_feature_tables_are_refused():
    nested = '{"type":"conjunction","a":' * 100000 + "1" + "}" * 100000
    with pytest.raises(ValueError, match="damaged feature table"):
        unpack_features({"blocks": [encode_text("[" + nested + "]")]})
    with pytest.raises(ValueError, match="not a list"):
        unpack_features({"blocks": [encode_text(json.dumps({"type": "texel"}))]})
    with pytest.raises(ValueError, match="no blocks"):
        unpack_features(encode_text("[]"))


def test_a_grown_table_packs_to_what_a_fresh_one_packs():
    from ftorch.checkpoint import Memo
    features = [Texel([float(i + 1)] + [0.5] * 14) for i in range(2 * CHUNK + 10)]
    grown = FeatureTable(memo=Memo())  # as a value cache's table grows, with the cache's memo
    for f in features[: CHUNK + 3]:
        grown.index(f)
    first = grown.pack()
    for f in features:
        grown.index(f)
    fresh = FeatureTable()
    for f in features:
        fresh.index(f)
    assert grown.pack() == fresh.pack() and len(grown.pack()["blocks"]) == 3
    assert grown.pack()["blocks"][0] is first["blocks"][0]  # the full first block was packed once
    assert unpack_features(grown.pack()) == features


def test_a_deeply_nested_or_old_checkpoint_file_gets_one_line(tmp_path):
    path = tmp_path / "deep.json"
    path.write_text("[" * 100000 + "]" * 100000)
    with pytest.raises(InputError, match="nested too deeply"):
        load_checkpoint(path, "fold")
    path.write_text(json.dumps({"format": "ftorch", "kind": "fold", "version": 1}))
    with pytest.raises(InputError, match="checkpoint version 1, this ftorch reads versions 2 to 4"):
        load_checkpoint(path, "fold")


def test_a_table_read_back_packs_its_blocks_as_read(monkeypatch):
    """A resumed run's first checkpoint reuses the blocks it read instead of compressing them again;
    a block that grew is packed afresh, and every block unpacks to its features."""
    from ftorch.checkpoint import Memo
    features = [Texel([float(i + 1)] + [0.25] * 14) for i in range(CHUNK + 5)]
    packed = FeatureTable({f: i for i, f in enumerate(features)}).pack()
    memo = Memo()  # a value cache's, as a resumed run reads its table into
    read = unpack_features(json.loads(json.dumps(packed)), memo)  # new objects, as a resumed run has
    compressed = []
    monkeypatch.setattr("ftorch.space.features.encode_text", lambda text: compressed.append(text) or encode_text(text))
    assert FeatureTable({f: i for i, f in enumerate(read)}).pack() == packed and len(compressed) == 2  # no memo: all again
    compressed.clear()
    table = FeatureTable({f: i for i, f in enumerate(read)}, memo)
    assert table.pack() == packed
    assert compressed == []  # nothing compressed again
    table.index(Texel([0.5] * 15))
    again = table.pack()
    assert again["blocks"][0] == packed["blocks"][0] and len(compressed) == 1  # only the grown last block
    assert unpack_features(again) == [*features, Texel([0.5] * 15)]


def test_blocks_are_compressed_once_and_remembered_without_a_copy_of_their_bytes():
    from ftorch.checkpoint import MEMO_SIZE, Memo
    values = np.random.default_rng(2).random((2 * ROWS, 64))
    memo = Memo()
    first = encode_array(values, memo=memo)
    again = encode_array(values.copy(), memo=memo)
    assert all(a is b for a, b in zip(again["blocks"], first["blocks"]))  # the same bytes: compressed once
    assert not any(a is b for a, b in zip(encode_array(values)["blocks"], first["blocks"]))  # without the memo: anew
    assert len(memo.arrays) == 2 and all(len(digest) == 32 for digest, _ in memo.arrays)  # a digest, not the 512 kB
    for n in range(MEMO_SIZE):
        encode_array(np.full((1, 1), n / MEMO_SIZE), memo=memo)
    assert len(memo.arrays) == MEMO_SIZE  # bounded: the oldest forgotten
