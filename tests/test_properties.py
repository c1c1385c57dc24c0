"""Property-based tests (hypothesis): the session reader and the hue functions on arbitrary inputs.

- The capture-session reader, given random corruptions of a valid session (bytes flipped, files
  truncated or deleted, session.yaml replaced by random YAML or with one value changed), either
  accepts the session or raises :class:`~huefringe.session.SessionError`, nothing else; so does
  :func:`~huefringe.session.read_rgb` on every image.
- The hue functions and :meth:`HueTable.to_phase` / :meth:`HueTable.from_phase` on arbitrary
  finite inputs return only their documented outputs: NaN or a float32 angle in [0, 2 pi).

Example counts are modest (<= 50 per test) so that the file runs in well under a minute.
"""

from __future__ import annotations

import copy
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from session_factory import make_session

from huefringe import colour
from huefringe.bench.toy import BandReader, ToyRig
from huefringe.huetable import HueTable, build_table
from huefringe.session import IMAGE_SUFFIXES, SessionError, load_session, read_rgb

TWO_PI_F32 = np.float32(2 * np.pi)
SETTINGS = settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def assert_angles(out: np.ndarray, shape: tuple[int, ...]) -> None:
    """Only the documented outputs: float32, NaN or in [0, 2 pi)."""
    assert out.dtype == np.float32 and out.shape == shape
    finite = ~np.isnan(out)
    assert np.all((out[finite] >= 0) & (out[finite] < TWO_PI_F32)), out[finite][~((out[finite] >= 0) & (out[finite] < TWO_PI_F32))]


# --------------------------------------------------------------------------------------------
# the session reader on corrupted sessions
# --------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def valid_session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = make_session(tmp_path_factory.mktemp("valid") / "s", width=16, height=16, bands=6, repeats=1, frames=1)
    load_session(root, deep=True)
    return root


def _files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*") if p.is_file())


yaml_scalars = st.one_of(
    st.none(), st.booleans(), st.integers(-(2**70), 2**70), st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12), st.sampled_from(["capture-session/1", "test-session", "step_heights"]),
)  # fmt: skip
yaml_values = st.recursive(
    yaml_scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)),
    max_leaves=12,
)
mutations = st.one_of(
    st.tuples(st.just("flip"), st.integers(0, 10**6), st.floats(0, 1), st.integers(1, 255)),
    st.tuples(st.just("truncate"), st.integers(0, 10**6), st.floats(0, 1)),
    st.tuples(st.just("delete"), st.integers(0, 10**6)),
    st.tuples(st.just("yaml"), yaml_values),
    st.tuples(st.just("text"), st.text(max_size=200)),
    st.tuples(st.just("set"), st.lists(st.integers(0, 20), min_size=1, max_size=4), yaml_values),
)


def _set_somewhere(meta: Any, path: list[int], value: Any) -> Any:
    """Replace one value of the (nested) session.yaml document, chosen by ``path``."""
    node = meta
    for i, step in enumerate(path):
        keys: list[Any] = list(node) if isinstance(node, dict) else list(range(len(node))) if isinstance(node, list) else []
        if not keys:
            break
        key = keys[step % len(keys)]
        if i == len(path) - 1 or not isinstance(node[key], dict | list):
            node[key] = value
            return meta
        node = node[key]
    return value if node is meta else meta


def _apply(root: Path, mutation: tuple[Any, ...]) -> None:
    kind = mutation[0]
    files = _files(root)
    if kind in ("flip", "truncate", "delete"):
        if not files:
            return
        path = files[mutation[1] % len(files)]
        if kind == "delete":
            path.unlink()
            return
        data = bytearray(path.read_bytes())
        if kind == "truncate":
            path.write_bytes(bytes(data[: int(len(data) * mutation[2])]))
        elif data:
            data[min(len(data) - 1, int(len(data) * mutation[2]))] ^= mutation[3]
            path.write_bytes(bytes(data))
    elif kind == "yaml":
        (root / "session.yaml").write_text(yaml.safe_dump(mutation[1]))
    elif kind == "text":
        (root / "session.yaml").write_text(mutation[1], encoding="utf-8", errors="surrogatepass")
    elif kind == "set":
        if not (root / "session.yaml").exists():
            return
        try:
            meta = yaml.safe_load((root / "session.yaml").read_text())
        except (yaml.YAMLError, UnicodeDecodeError):
            return  # already broken by an earlier mutation
        (root / "session.yaml").write_text(yaml.safe_dump(_set_somewhere(copy.deepcopy(meta), mutation[1], mutation[2])))


@SETTINGS
@given(st.lists(mutations, min_size=1, max_size=3))
def test_session_reader_raises_only_session_error(valid_session: Path, muts: list[tuple[Any, ...]]) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(shutil.copytree(valid_session, Path(tmp) / "s"))
        for m in muts:
            _apply(root, m)
        try:
            s = load_session(root, deep=True)
        except SessionError as exc:
            assert exc.problems and str(exc)
        else:
            assert s.frame_ids and s.width == 16
        for p in _files(root):
            if p.suffix.lower() in IMAGE_SUFFIXES:
                try:
                    img = read_rgb(p)
                except SessionError as exc:
                    assert str(p) in str(exc)
                else:
                    assert img.dtype == np.float32 and img.ndim == 3 and img.shape[2] == 3


# --------------------------------------------------------------------------------------------
# hue functions on arbitrary finite inputs
# --------------------------------------------------------------------------------------------

finite64 = st.floats(allow_nan=False, allow_infinity=False)
finite32 = st.floats(allow_nan=False, allow_infinity=False, width=32)
rgb_arrays = st.one_of(
    arrays(np.float64, st.tuples(st.integers(1, 8), st.just(3)), elements=finite64),
    arrays(np.float32, st.tuples(st.integers(1, 8), st.just(3)), elements=finite32),
    arrays(np.float64, st.tuples(st.integers(1, 8), st.just(3)), elements=st.floats(0, 1)),
)


@SETTINGS
@given(rgb_arrays, st.sampled_from(["hexcone", "hsi"]), st.floats(0, 1))
def test_hue_functions_return_nan_or_an_angle_in_0_2pi(rgb: np.ndarray, model: str, min_sat: float) -> None:
    shape = rgb.shape[:1]
    with np.errstate(all="ignore"):  # overflow of huge inputs is allowed; the output must stay documented
        for f in (colour.hue_hexcone, colour.hue_hsi, colour.hue_hsi_arccos):
            assert_angles(f(rgb), shape)
        assert_angles(colour.hue(rgb, model, min_saturation=min_sat), shape)  # type: ignore[arg-type]
        assert_angles(colour.wrap_2pi(rgb[:, 0]), shape)
        grey = np.repeat(np.clip(rgb[:, :1], -1e30, 1e30), 3, axis=1)  # R = G = B (no overflow in R - (G + B) / 2)
        assert np.isnan(colour.hue_hexcone(grey)).all() and np.isnan(colour.hue_hsi(grey)).all()


@pytest.fixture(scope="module")
def table() -> HueTable:
    """A valid per-pixel table of a small simulated rig (gamma, crosstalk, coloured surface)."""
    refl = np.empty((3, 4, 3))
    refl[:] = (0.8, 0.6, 0.5)
    refl[1] = (0.4, 0.7, 0.9)
    rig = ToyRig(reflectance=refl, crosstalk=np.array([[0.9, 0.08, 0.02], [0.07, 0.86, 0.07], [0.02, 0.1, 0.88]]), seed=5)
    reader = BandReader(rig, 16)
    t = build_table(reader.paths(2), rig.white(), read=reader, smooth_window=5)
    assert t.valid.all()
    t.valid[0, 0] = False  # one masked pixel: NaN whatever the hue
    return t


hue_maps = st.one_of(
    arrays(np.float64, (3, 4), elements=st.floats(-1e6, 1e6) | st.just(np.nan)),
    arrays(np.float32, (3, 4), elements=st.floats(-1e6, 1e6, width=32) | st.just(np.nan)),
    arrays(np.float64, (3, 4), elements=st.floats(-1e-300, 1e-300) | st.floats(2 * np.pi - 1e-6, 2 * np.pi + 1e-6)),
)


@SETTINGS
@given(hue_maps)
def test_to_phase_on_realistic_hues_is_nan_or_in_0_2pi(table: HueTable, hue: np.ndarray) -> None:
    for method in ("numba", "numpy"):
        out = table.to_phase(hue, method=method)  # type: ignore[arg-type]
        assert_angles(out, (3, 4))
        assert np.isnan(out[0, 0])
        assert np.array_equal(np.isnan(out), np.isnan(hue) | ~table.valid)
    assert_angles(table.from_phase(np.nan_to_num(hue)), (3, 4))


@settings(max_examples=30, deadline=None)
@example(hue=np.full((3, 4), -1e20))
@given(arrays(np.float64, (3, 4), elements=finite64))
def test_to_phase_on_any_finite_hue_is_nan_or_in_0_2pi(table: HueTable, hue: np.ndarray) -> None:
    with np.errstate(all="ignore"):
        for method in ("numba", "numpy"):
            assert_angles(table.to_phase(hue, method=method), (3, 4))  # type: ignore[arg-type]
