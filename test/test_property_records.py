"""Property-based tests of the record readers (random bytes, cuts, dtypes, shapes).

Any input gives a Record or one DataError naming the file; never another exception, never a NaN
in a loaded record.
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np
from _hypothesis_profiles import settings  # noqa: F401 - registers and loads the profile
from hypothesis import assume, given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from okid_ros.errors import DataError
from okid_ros.records import load_record

DTYPES = st.sampled_from(["f8", "f4", "f2", "i8", "i1", "u2", "?", "c16", "U3", "S2", "g", "M8[s]"])


def _load(tmp: Path, name: str, payload: bytes):
    path = tmp / name
    path.write_bytes(payload)
    try:
        return path, load_record(path)
    except DataError as exc:
        text = str(exc)
        assert text.startswith(f"{path}: ") and "\n" not in text
        return path, None


def _good_npz(n: int = 40) -> bytes:
    stream = io.BytesIO()
    rng = np.random.default_rng(n)
    np.savez(stream, u=rng.standard_normal((n, 2)), y=rng.standard_normal((n, 1)), sample_time_s=0.01)
    return stream.getvalue()


def _check_loaded(record) -> None:
    if record is None:
        return
    assert record.u.dtype == float and record.y.dtype == float
    assert record.u.ndim == 2 and record.y.ndim == 2 and record.u.shape[0] == record.y.shape[0] > 0
    assert record.y.shape[1] >= 1
    assert np.isfinite(record.u).all() and np.isfinite(record.y).all()
    assert np.isfinite(record.sample_time_s) and record.sample_time_s > 0


@given(payload=st.binary(max_size=2000), suffix=st.sampled_from([".npz", ".csv"]))
def test_random_bytes_are_a_record_or_one_line(tmp_path_factory, payload: bytes, suffix: str) -> None:
    _, record = _load(tmp_path_factory.mktemp("bytes"), f"r{suffix}", payload)
    _check_loaded(record)


@given(cut=st.integers(min_value=0, max_value=len(_good_npz()) - 1), flip=st.integers(0, 255),
       at=st.integers(min_value=0, max_value=len(_good_npz()) - 1))
def test_truncated_or_damaged_npz_is_one_line(tmp_path_factory, cut: int, flip: int, at: int) -> None:
    good = bytearray(_good_npz())
    good[at] ^= flip
    _, record = _load(tmp_path_factory.mktemp("cut"), "r.npz", bytes(good[: max(cut, 1)]))
    _check_loaded(record)


@given(u=hnp.arrays(DTYPES, hnp.array_shapes(min_dims=0, max_dims=3, max_side=6)),
       y=hnp.arrays(DTYPES, hnp.array_shapes(min_dims=0, max_dims=3, max_side=6)),
       dt=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.just("0.01"), st.just([0.1, 0.2]),
                    st.complex_numbers(max_magnitude=1)),
       with_u=st.booleans())
def test_any_dtype_and_shape_is_a_record_or_one_line(tmp_path_factory, u, y, dt, with_u: bool) -> None:
    stream = io.BytesIO()
    arrays = {"y": y, "sample_time_s": np.asarray(dt)}
    if with_u:
        arrays["u"] = u
    np.savez(stream, **arrays)
    _, record = _load(tmp_path_factory.mktemp("dtype"), "r.npz", stream.getvalue())
    _check_loaded(record)


@given(n=st.integers(1, 30), m=st.integers(0, 3), p=st.integers(1, 3),
       scale=st.sampled_from([1.0, 1e-300, 1e300, 1e-150, 1e150]))
def test_valid_records_load_exactly(tmp_path_factory, n: int, m: int, p: int, scale: float) -> None:
    rng = np.random.default_rng(n * 100 + m * 10 + p)
    u, y = rng.standard_normal((n, m)) * scale, rng.standard_normal((n, p)) * scale
    stream = io.BytesIO()
    np.savez(stream, **({"u": u} if m else {}), y=y, sample_time_s=0.004)
    _, record = _load(tmp_path_factory.mktemp("valid"), "r.npz", stream.getvalue())
    assert record is not None and record.u.shape == (n, m)
    np.testing.assert_array_equal(record.u, u)
    np.testing.assert_array_equal(record.y, y)


@given(text=st.text(alphabet=st.sampled_from(list("uy0123456789.,-e# \n=_abcinfts")), max_size=300))
def test_any_csv_text_is_a_record_or_one_line(tmp_path_factory, text: str) -> None:
    _, record = _load(tmp_path_factory.mktemp("csv"), "r.csv", text.encode())
    _check_loaded(record)


@given(member=st.sampled_from(["u.npy", "y.npy", "sample_time_s.npy"]), junk=st.binary(max_size=200))
def test_npz_with_a_damaged_member_is_one_line(tmp_path_factory, member: str, junk: bytes) -> None:
    source = zipfile.ZipFile(io.BytesIO(_good_npz()))
    stream = io.BytesIO()
    with zipfile.ZipFile(stream, "w") as target:
        for info in source.infolist():
            target.writestr(info.filename, junk if info.filename == member else source.read(info))
    assume(junk != source.read(member))
    _, record = _load(tmp_path_factory.mktemp("member"), "r.npz", stream.getvalue())
    assert record is None
