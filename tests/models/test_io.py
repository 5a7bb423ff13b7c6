import json
import subprocess
import sys
import textwrap
import zipfile

import numpy as np
import pytest
import torch

from models import ModelFileError, WorldModel, finger_graph, load, save
from models import io as model_io
from models.io import FORMAT, KEY_ENV, ModelFileTooLargeError, ModelSignatureError, ReadLimits, read_metadata


@pytest.fixture
def model():
    torch.manual_seed(3)
    m = WorldModel(finger_graph("state"))
    m.set_root_prior("q_prev.finger", -1.7, 0.8)
    return m


def inputs():
    g = torch.Generator().manual_seed(0)
    return {
        "act.finger": torch.rand(7, 1, generator=g) - 0.5,
        "q_prev.finger": torch.randn(7, 1, generator=g),
    }


def test_round_trip_gives_identical_predictions(model, tmp_path):
    path = save(model, tmp_path / "wm.npz", provenance={"seed": 3, "config": {"epochs": 1}})
    loaded = load(path, finger_graph("state"))
    with torch.no_grad():
        a, b = model.predict(inputs()), loaded.predict(inputs())
    for k in a:
        assert torch.equal(a[k], b[k])
    assert loaded.provenance["seed"] == 3
    assert "torch" in loaded.provenance["versions"]
    meta = read_metadata(path)
    assert meta["mechanisms"]["dq.finger"]["hidden"] == [32, 32]
    # no pickle: every entry loads with allow_pickle=False
    with np.load(path, allow_pickle=False) as npz:
        assert all(npz[k].dtype != object for k in npz.files)


@pytest.mark.slow
def test_load_in_a_fresh_process(model, tmp_path):
    path = save(model, tmp_path / "wm.npz")
    with torch.no_grad():
        expected = model.predict(inputs())["q.finger"].numpy().ravel().tolist()
    script = textwrap.dedent(
        f"""
        import json, torch
        torch.set_num_threads(1)  # the same kernels as the test process
        from models import load, finger_graph
        g = torch.Generator().manual_seed(0)
        x = {{"act.finger": torch.rand(7, 1, generator=g) - 0.5, "q_prev.finger": torch.randn(7, 1, generator=g)}}
        m = load({str(path)!r}, finger_graph("state"))
        with torch.no_grad():
            print(json.dumps(m.predict(x)["q.finger"].numpy().ravel().tolist()))
        """
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert json.loads(out.stdout) == expected


def test_refuses_other_graph(model, tmp_path):
    path = save(model, tmp_path / "wm.npz")
    with pytest.raises(ModelFileError, match="does not match the expected"):
        load(path, finger_graph("thesis"))


def test_refuses_corrupted_and_truncated_files(model, tmp_path):
    path = save(model, tmp_path / "wm.npz")
    blob = path.read_bytes()
    (tmp_path / "trunc.npz").write_bytes(blob[: len(blob) // 2])
    with pytest.raises(ModelFileError, match="not a readable world-model file"):
        load(tmp_path / "trunc.npz")
    (tmp_path / "garbage.npz").write_bytes(b"not a zip at all")
    with pytest.raises(ModelFileError, match="not a readable"):
        load(tmp_path / "garbage.npz")
    with pytest.raises(ModelFileError, match="no world-model file"):
        load(tmp_path / "missing.npz")
    # a tensor altered on disk fails the checksum
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k].copy() for k in npz.files}
    key = next(k for k in arrays if k.startswith("state/") and arrays[k].size > 1)
    arrays[key][0] += 1.0
    np.savez(tmp_path / "tampered.npz", **arrays)
    with pytest.raises(ModelFileError, match="checksum mismatch"):
        load(tmp_path / "tampered.npz")
    # an npz that is not a model
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(ModelFileError, match="no __meta__ entry"):
        load(tmp_path / "other.npz")
    # a pickled object array is refused before anything is unpickled
    np.savez(tmp_path / "pickled.npz", __meta__=np.array([{"a": 1}], dtype=object))
    with pytest.raises(ModelFileError, match="dtype object"):
        load(tmp_path / "pickled.npz")
    assert zipfile.is_zipfile(path)


def test_save_is_atomic_and_leaves_no_temp_files(model, tmp_path):
    save(model, tmp_path / "wm.npz")
    save(model, tmp_path / "wm.npz")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["wm.npz"]


def test_save_rejects_unserialisable_mechanisms_and_provenance(tmp_path):
    from models import FunctionMechanism, chain_graph

    m = WorldModel(chain_graph(), {"y": FunctionMechanism(torch.sin, 1)})
    with pytest.raises(ValueError, match="cannot be saved"):
        save(m, tmp_path / "x.npz")
    with pytest.raises(ValueError, match="not JSON-serialisable"):
        save(WorldModel(chain_graph()), tmp_path / "y.npz", provenance={"bad": object()})
    assert not (tmp_path / "y.npz").exists()


def _edit(path, edit, *, fix_checksum=False):
    """Rewrite the JSON metadata of a saved model with ``edit(doc)`` (keeping the old checksum)."""
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    doc = json.loads(arrays.pop("__meta__").tobytes())
    edit(doc)
    if fix_checksum:  # a deliberate edit that also recomputes the checksum
        doc["checksum"] = model_io._checksum(doc["format"], doc["versions"], doc["meta"], arrays)
    arrays["__meta__"] = np.frombuffer(json.dumps(doc).encode(), dtype=np.uint8)
    np.savez(path, **arrays)


def _variable(doc, name):
    return next(v for v in doc["meta"]["graph"]["variables"] if v["name"] == name)


@pytest.mark.parametrize(
    "edit",
    [
        lambda d: d["meta"]["mechanisms"]["dq.finger"].update(activation="relu"),
        lambda d: _variable(d, "act.finger").update(bounds=[[-2.0], [2.0]]),
        lambda d: _variable(d, "dq.finger").update(role="observed"),
        lambda d: d["meta"]["provenance"].update(seed=4),
        lambda d: d["versions"].update(torch="0.0"),
    ],
    ids=["activation", "action-bounds", "role", "provenance", "versions"],
)
def test_edited_metadata_is_refused(model, tmp_path, edit):
    path = save(model, tmp_path / "wm.npz", provenance={"seed": 3})
    _edit(path, edit)
    with pytest.raises(ModelFileError, match="checksum mismatch"):
        load(path)


@pytest.mark.parametrize(
    "name, change", [("act.finger", {"bounds": [[-2.0], [2.0]]}), ("dq.finger", {"role": "observed"})]
)
def test_an_edited_graph_fails_its_fingerprint_even_with_a_fixed_checksum(model, tmp_path, name, change):
    path = save(model, tmp_path / "wm.npz")
    _edit(path, lambda d: _variable(d, name).update(change), fix_checksum=True)
    with pytest.raises(ModelFileError, match="does not match its fingerprint"):
        load(path)


def test_the_checksum_covers_dtype_and_shape(model, tmp_path):
    path = save(model, tmp_path / "wm.npz")
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    key = next(k for k in arrays if k.startswith("state/") and arrays[k].ndim == 2)
    for changed in (arrays[key].T.copy(), arrays[key].view(np.int32)):  # same bytes, other shape / dtype
        np.savez(tmp_path / "x.npz", **{**arrays, key: changed})
        with pytest.raises(ModelFileError, match="checksum mismatch"):
            load(tmp_path / "x.npz")


def test_save_refuses_nan_parameters_and_provenance_naming_them(model, tmp_path):
    with pytest.raises(ValueError, match=r"provenance\['loss'\]\[1\] is nan"):
        save(model, tmp_path / "wm.npz", provenance={"loss": [0.1, float("nan")]})
    with torch.no_grad():
        next(iter(model.mechanism("dq.finger").parameters())).view(-1)[0] = float("inf")
    name = next(k for k, v in model.state_dict().items() if not torch.isfinite(v).all())
    with pytest.raises(ValueError, match=rf"parameter '{name}' has 1 NaN/inf entries"):
        save(model, tmp_path / "wm.npz")
    assert not (tmp_path / "wm.npz").exists()


def test_an_older_format_gets_a_clear_error(model, tmp_path):
    path = save(model, tmp_path / "wm.npz")
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    old = {"format": "pal.world_model/1", "graph": {}, "checksum": "0"}
    arrays["__meta__"] = np.frombuffer(json.dumps(old).encode(), dtype=np.uint8)
    np.savez(path, **arrays)
    with pytest.raises(ModelFileError, match=rf"pal.world_model/1 file, an older format.*reads {FORMAT}"):
        load(path)


def test_float64_models_keep_their_precision(tmp_path):
    torch.manual_seed(0)
    m = WorldModel(finger_graph("state")).double()
    loaded = load(save(m, tmp_path / "wm.npz"))
    for (k, a), b in zip(m.state_dict().items(), loaded.state_dict().values(), strict=True):
        assert b.dtype == torch.float64 and torch.equal(a, b), k


def test_size_limits_are_checked_before_reading(model, tmp_path):
    path = save(model, tmp_path / "wm.npz")
    with pytest.raises(model_io.ModelFileTooLargeError, match="more than the 1000 allowed"):
        load(path, limits=ReadLimits(max_bytes=1000))
    assert load(path, limits=ReadLimits(max_bytes=10**6)) is not None


# ---------------------------------------------------------------------------- new mechanisms
@pytest.mark.parametrize(("kind", "members"), [("hetero", 1), ("mlp", 3), ("hetero", 2), ("linear", 2)])
def test_heteroscedastic_and_ensemble_models_round_trip(tmp_path, kind, members):
    m = WorldModel(finger_graph("state"), seed=4, kind=kind, members=members, hidden=(5,))
    with torch.no_grad():  # move the learned bounds off their initial values
        for name, p in m.named_parameters():
            if "log_scale_m" in name:
                p.add_(0.25)
    path = save(m, tmp_path / "wm.npz")
    loaded = load(path, finger_graph("state"))
    assert read_metadata(path)["format"] == FORMAT == "pal.world_model/3"
    for name in m.graph.non_roots:
        assert loaded.mechanism(name).config() == m.mechanism(name).config()
        assert type(loaded.mechanism(name)) is type(m.mechanism(name))
    for (k, a), (_, b) in zip(m.state_dict().items(), loaded.state_dict().items(), strict=True):
        assert torch.equal(a, b), k
    with torch.no_grad():
        for a, b in (
            (m.predict(inputs(), members=True), loaded.predict(inputs(), members=True)),
            (m.predict_scale(inputs()), loaded.predict_scale(inputs())),
        ):
            for k in a:
                assert torch.equal(a[k], b[k]), k
    assert loaded.ensemble_size == members


def test_a_version_2_file_still_loads(model, tmp_path, monkeypatch):
    monkeypatch.setattr(model_io, "FORMAT", "pal.world_model/2")
    path = save(model, tmp_path / "wm.npz")
    monkeypatch.undo()
    assert read_metadata(path)["format"] == "pal.world_model/2"
    loaded = load(path)
    with torch.no_grad():
        a, b = model.predict(inputs()), loaded.predict(inputs())
    assert all(torch.equal(a[k], b[k]) for k in a)
    _edit(path, lambda d: d.update(format="pal.world_model/9"))
    with pytest.raises(ModelFileError, match="format 'pal.world_model/9', expected one of"):
        load(path)


def test_an_ensemble_holding_a_function_cannot_be_saved(tmp_path):
    from models import EnsembleMechanism, FunctionMechanism, chain_graph

    ens = EnsembleMechanism([FunctionMechanism(torch.sin, 1), FunctionMechanism(torch.cos, 1)])
    with pytest.raises(
        ValueError, match="mechanism of 'y' is \\(or holds\\) a FunctionMechanism, which cannot be saved"
    ):
        save(WorldModel(chain_graph(), {"y": ens}), tmp_path / "x.npz")
    assert not (tmp_path / "x.npz").exists()


def test_a_model_with_discrete_sites_round_trips(tmp_path):
    from models import BernoulliMechanism, CategoricalMechanism, CausalGraph, Variable, WorldModel, load, save

    graph = CausalGraph(
        [Variable(n, "observed") for n in "rtcy"], [("r", "t"), ("r", "c"), ("t", "y"), ("c", "y")]
    )
    model = WorldModel(
        graph,
        {"t": BernoulliMechanism(3, seed=0), "c": CategoricalMechanism(3, 4, hidden=(5,), seed=1)},
        seed=2,
        discrete={"r": 3},
    )
    model.set_root_probs("r", [0.2, 0.3, 0.5])
    path = save(model, tmp_path / "discrete.npz")
    back = load(path)
    assert back.discrete == {"r": 3, "t": 2, "c": 4}
    assert back.parent_dim("y") == 1 + 4
    values = model.sample(50, torch.Generator().manual_seed(0))
    again = back.sample(50, torch.Generator().manual_seed(0))
    for k in values:
        torch.testing.assert_close(values[k], again[k])


# ---------------------------------------------------------------------------- signatures and bombs
def _scale_weights(path, factor):
    """Multiply every float tensor by ``factor`` and recompute the checksum: a deliberate forgery."""
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    doc = json.loads(arrays.pop("__meta__").tobytes())
    arrays = {k: v * factor if v.dtype.kind == "f" else v for k, v in arrays.items()}
    doc["checksum"] = model_io._checksum(doc["format"], doc["versions"], doc["meta"], arrays)
    arrays["__meta__"] = np.frombuffer(json.dumps(doc).encode(), dtype=np.uint8)
    np.savez(path, **arrays)


def test_a_forged_file_with_a_recomputed_checksum_loads_unless_a_key_is_required(model, tmp_path):
    path = save(model, tmp_path / "wm.npz", key=b"secret")
    assert load(path, key="secret") is not None and load(path) is not None  # str and bytes keys
    _scale_weights(path, 10.0)
    forged = load(path)  # without a key the checksum alone cannot tell
    assert forged is not None
    with pytest.raises(ModelSignatureError, match=r"wm\.npz has a signature that does not match the key"):
        load(path, key=b"secret")
    other = save(model, tmp_path / "other.npz", key=b"another key")
    with pytest.raises(ModelSignatureError, match=r"other\.npz has a signature that does not match"):
        load(other, key=b"secret")
    unsigned = save(model, tmp_path / "plain.npz")
    with pytest.raises(ModelSignatureError, match=r"plain\.npz is not signed, but a key was given"):
        load(unsigned, key=b"secret")
    with pytest.raises(ModelSignatureError, match="is not signed"):
        read_metadata(unsigned, key=b"secret")
    for bad in (b"", "", 3):
        with pytest.raises(ValueError, match="key must be non-empty bytes or str"):
            save(model, tmp_path / "x.npz", key=bad)


def test_the_key_comes_from_the_environment_when_not_given(model, tmp_path, monkeypatch):
    monkeypatch.setenv(KEY_ENV, "from-env")
    assert KEY_ENV == "PAL_MODEL_KEY"
    path = save(model, tmp_path / "wm.npz")  # signed with the environment's key
    assert load(path) is not None and load(path, key="from-env") is not None
    with pytest.raises(ModelSignatureError, match="does not match the key"):
        load(path, key="another")
    monkeypatch.delenv(KEY_ENV)
    unsigned = save(model, tmp_path / "plain.npz")
    monkeypatch.setenv(KEY_ENV, "from-env")
    with pytest.raises(ModelSignatureError, match="is not signed"):
        load(unsigned)


def test_content_far_beyond_the_file_size_is_refused_before_inflating(model, tmp_path):
    from tests.hostile import npz_bomb

    path = npz_bomb(tmp_path / "bomb.npz", "state/w", n_bytes=128 << 20)  # 128 MiB of zeros in ~130 kB
    with pytest.raises(
        ModelFileTooLargeError,
        match=r"bomb\.npz declares 134217856 bytes of content in a file of \d+ bytes, a compression ratio of \d+",
    ):
        load(path)
    with pytest.raises(
        ModelFileError, match=r"bomb\.npz has no __meta__"
    ):  # a larger ratio allowed: read, then refused
        load(path, limits=ReadLimits(max_ratio=10_000))
    with pytest.raises(ValueError, match="ReadLimits.max_ratio"):
        ReadLimits(max_ratio=0)
