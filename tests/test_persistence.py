"""Saving and loading models and demonstrations: exact round trips and every error path."""

import io
import json
import pickle
import struct
import zipfile

import numpy as np
from helpers import hang_guard
import pytest

import factirl_opt as fo
import solvers
from factirl_opt.exceptions import PersistenceError, ValidationError
from factirl_opt.mdp.tabular import check_signature
from factirl_opt.objectives import PolicyMatchingObjective
from factirl_opt.persistence import FORMAT_VERSION
from factirl_opt.tasks.trajectories import parse_demonstrations


@pytest.fixture(scope="module")
def setting():
    mdp = fo.GridWorld(size=4)
    rng = np.random.default_rng(11)
    D = fo.random_dictionary(mdp.n_params, 2, rng=rng)
    rewards = fo.task_rewards(D, fo.random_coefficients(5, 2, rng=rng), mdp.n_states, mdp.n_actions)
    demos = fo.sample_demonstrations(mdp, rewards, n_demos=3, length=6, rng=rng)
    new_rewards = fo.task_rewards(D, fo.random_coefficients(3, 2, rng=rng), mdp.n_states, mdp.n_actions)
    new_demos = fo.sample_demonstrations(mdp, new_rewards, n_demos=1, length=10, rng=rng)
    return mdp, rewards, demos, new_rewards, new_demos


@pytest.fixture(scope="module")
def fitted(setting):
    mdp, _, demos, _, _ = setting
    return fo.FactIRL(n_primitives=2, max_iter=5, inner_steps=3, flat_max_iter=10, transfer_max_iter=15,
                      rng=np.random.default_rng(5)).fit(mdp, demos)


def _header(path):
    with np.load(path, allow_pickle=False) as npz:
        return json.loads(str(npz["__header__"][()])), {k: npz[k] for k in npz.files if k != "__header__"}


def _rewrite(src, dst, edit_header=None, drop=(), extra=None):
    header, arrays = _header(src)
    if edit_header:
        edit_header(header)
    for key in drop:
        arrays.pop(key)
    arrays.update(extra or {})
    np.savez(dst, __header__=np.array(json.dumps(header)), **arrays)
    return dst


# ----------------------------------------------------------------------------- round trips


def test_factirl_round_trip_transfers_bit_identically(setting, fitted, tmp_path):
    mdp, _, _, new_rewards, new_demos = setting
    path = fo.save_model(fitted, tmp_path / "model")  # no suffix added
    assert path == str(tmp_path / "model") and (tmp_path / "model").exists()
    loaded = fo.load_model(path)
    assert type(loaded) is fo.FactIRL
    for name in ("n_primitives", "beta", "init", "max_iter", "inner_steps", "tol", "solver", "solver_options",
                 "flat_max_iter", "transfer_max_iter"):
        assert getattr(loaded, name) == getattr(fitted, name)
    for name in ("dictionary_", "coefficients_", "rewards_", "loss_"):
        a, b = getattr(fitted, name), getattr(loaded, name)
        assert a.dtype == b.dtype and np.array_equal(a, b)
    assert loaded.loss_history_ == fitted.loss_history_
    assert (loaded.n_iter_, loaded.n_evaluations_) == (fitted.n_iter_, fitted.n_evaluations_)
    h_orig = fitted.transfer(mdp, new_demos)
    h_load = loaded.transfer(mdp, new_demos)
    assert h_orig.tobytes() == h_load.tobytes()
    learnt = fo.task_rewards(loaded.dictionary_, h_load, mdp.n_states, mdp.n_actions)
    np.testing.assert_array_equal(fo.score(mdp, new_rewards, learnt), fo.score(mdp, new_rewards, fitted.transfer_rewards_))
    assert loaded.transfer_loss_history_ == fitted.transfer_loss_history_


def test_header_records_versions_and_parameters(fitted, tmp_path):
    header, arrays = _header(fo.save_model(fitted, tmp_path / "m.npz"))
    assert header["format"] == "factirl-opt" and header["format_version"] == FORMAT_VERSION
    assert header["kind"] == "model" and header["class"] == "FactIRL"
    assert header["library_version"] == fo.__version__ and header["numpy_version"] == np.__version__
    assert header["params"]["n_primitives"] == 2 and header["params"]["solver"] == "armijo"
    assert {"attr/dictionary_", "attr/coefficients_"} <= set(arrays)
    assert all(a.dtype != object for a in arrays.values())


def test_rng_generator_state_is_restored(setting, tmp_path):
    mdp, _, demos, _, _ = setting
    model = fo.FactIRL(n_primitives=2, init="random", max_iter=2, rng=np.random.default_rng(3))
    loaded = fo.load_model(fo.save_model(model, tmp_path / "m.npz"))
    assert isinstance(loaded.rng, np.random.Generator) and loaded.rng is not model.rng
    assert loaded.rng.bit_generator.state == model.rng.bit_generator.state
    np.testing.assert_array_equal(loaded.fit(mdp, demos).dictionary_, model.fit(mdp, demos).dictionary_)
    for rng in (None, 42, np.random.SeedSequence(9, spawn_key=(1, 2))):
        back = fo.load_model(fo.save_model(fo.FactIRL(rng=rng), tmp_path / "r.npz")).rng
        if isinstance(rng, np.random.SeedSequence):
            assert (back.entropy, back.spawn_key) == (rng.entropy, rng.spawn_key)
            assert np.array_equal(back.generate_state(4), rng.generate_state(4))
        else:
            assert back == rng


def test_gradirl_with_features_and_options_round_trip(setting, tmp_path):
    mdp, rewards, demos, _, _ = setting
    F = np.random.default_rng(0).standard_normal((mdp.n_params, 3))
    model = fo.GradIRL(beta=np.float64(4.0), features=F, max_iter=np.int64(10),
                       solver=fo.SolverSettings("armijo", {"initial_step": 0.5})).fit(mdp, demos)
    loaded = fo.load_model(fo.save_model(model, tmp_path / "flat.npz"))
    assert type(loaded) is fo.GradIRL
    np.testing.assert_array_equal(loaded.features, F)
    assert loaded.solver.h_options == {"initial_step": 0.5} and loaded.max_iter == 10 and loaded.beta == 4.0
    np.testing.assert_array_equal(loaded.weights_, model.weights_)
    np.testing.assert_array_equal(fo.score(mdp, rewards, loaded.rewards_), fo.score(mdp, rewards, model.rewards_))
    assert loaded.status_ == model.status_
    refit = loaded.fit(mdp, demos)
    np.testing.assert_array_equal(refit.weights_, model.weights_)


def test_tuple_init_unfitted_model_and_file_objects(setting):
    mdp, _, demos, _, _ = setting
    D0 = np.random.default_rng(1).standard_normal((mdp.n_params, 2))
    H0 = np.ones((5, 2))
    model = fo.FactIRL(n_primitives=2, init=(D0, H0), max_iter=2)
    buf = io.BytesIO()
    fo.save_model(model, buf)
    buf.seek(0)
    loaded = fo.load_model(buf)
    assert not hasattr(loaded, "dictionary_")
    assert isinstance(loaded.init, tuple)
    np.testing.assert_array_equal(loaded.init[0], D0)
    np.testing.assert_array_equal(loaded.fit(mdp, demos).rewards_, model.fit(mdp, demos).rewards_)


def test_ragged_demonstrations_round_trip(setting, tmp_path):
    mdp, _, demos, _, _ = setting
    ragged = [
        demos[0],  # (m, L, 2) array
        [demos[1][0][:2], demos[1][1], [[0, 1], [4, 2], [5, 3]]],  # list of episodes, lengths 2, 6, 3
        [demos[2][0]],  # a list of one (L, 2) episode
        (np.array([[3, 1]], dtype=np.int32),),
        demos[3].astype(np.float64),
    ]
    path = fo.save_demonstrations(ragged, tmp_path / "demos.npz")
    back = fo.load_demonstrations(path)
    assert len(back) == 5
    assert isinstance(back[0], np.ndarray) and back[0].shape == (3, 6, 2)
    assert isinstance(back[1], list) and [len(ep) for ep in back[1]] == [2, 6, 3]
    assert isinstance(back[2], list) and len(back[2]) == 1 and back[2][0].shape == (6, 2)
    assert isinstance(back[3], list) and back[3][0].tolist() == [[3, 1]]
    assert all(np.asarray(ep).dtype == np.int64 for task in back for ep in (task if isinstance(task, list) else [task]))
    np.testing.assert_array_equal(back[1][2], [[0, 1], [4, 2], [5, 3]])
    for a, b in zip(fo.empirical_statistics(mdp, ragged), fo.empirical_statistics(mdp, back)):
        np.testing.assert_array_equal(a, b)
    stacked = fo.load_demonstrations(fo.save_demonstrations(np.stack(demos), tmp_path / "stacked.npz"))
    assert all(np.array_equal(a, b) for a, b in zip(stacked, demos))


def test_learners_record_their_mdp_and_loaded_models_refuse_another(setting, fitted, tmp_path):
    mdp, _, demos, _, new_demos = setting
    flat = fo.GradIRL(max_iter=5).fit(mdp, demos)
    for model in (flat, fitted):
        loaded = fo.load_model(fo.save_model(model, tmp_path / "m.npz"))
        assert loaded.mdp_signature_ == model.mdp_signature_ == mdp.signature()
    other = fo.TabularMDP(np.full((32, 2, 32), 1 / 32), 0.9)  # S*A = 64 as well
    loaded = fo.load_model(fo.save_model(fitted, tmp_path / "f.npz"))
    np.testing.assert_array_equal(loaded.transfer(mdp, new_demos), fitted.transfer(mdp, new_demos))
    with pytest.raises(ValidationError, match="fitted on another MDP"):
        loaded.transfer(other, [[[0, 1]]])


def test_factirl_with_state_features_round_trip(setting, tmp_path):
    mdp, _, demos, _, new_demos = setting
    Phi = np.random.default_rng(4).standard_normal((mdp.n_states, 5))  # state features (S, p)
    model = fo.FactIRL(n_primitives=2, features=Phi, max_iter=3, flat_max_iter=5, transfer_max_iter=5, rng=0).fit(mdp, demos)
    loaded = fo.load_model(fo.save_model(model, tmp_path / "phi.npz"))
    np.testing.assert_array_equal(loaded.features, Phi)
    assert loaded.dictionary_.shape == model.dictionary_.shape
    assert loaded.transfer(mdp, new_demos).tobytes() == model.transfer(mdp, new_demos).tobytes()


def test_callback_is_not_saved(setting, tmp_path):
    mdp, _, demos, _, _ = setting
    seen = []
    model = fo.GradIRL(max_iter=3, execution=fo.Execution(callback=lambda *args: seen.append(args))).fit(mdp, demos)
    assert seen
    header, _ = _header(fo.save_model(model, tmp_path / "cb.npz"))
    assert not any("callback" in key for key in header["params"])
    loaded = fo.load_model(tmp_path / "cb.npz")
    assert loaded.execution.callback is None
    np.testing.assert_array_equal(loaded.weights_, model.weights_)
    with pytest.raises(PersistenceError, match="'execution__callback' is never saved"):
        fo.load_model(_rewrite(tmp_path / "cb.npz", tmp_path / "bad.npz",
                               lambda h: h["params"].update(execution__callback="print")))


# ----------------------------------------------------------------------------- errors on save


def test_save_model_refuses_what_it_cannot_store(fitted, tmp_path):
    with pytest.raises(ValidationError, match="model must be one of GradIRL, FactIRL, MultiIntentIRL; got dict"):
        fo.save_model({}, tmp_path / "x.npz")
    with pytest.raises(PersistenceError, match="solver given as a ArmijoSolver object.*registry name"):
        fo.save_model(fo.FactIRL(solver=solvers.ArmijoSolver()), tmp_path / "x.npz")
    with pytest.raises(PersistenceError, match="solver given as a ArmijoSolver object"):
        fo.save_model(fo.GradIRL(solver=solvers.get_solver("armijo")), tmp_path / "x.npz")
    with pytest.raises(PersistenceError, match="d_solver given as a ArmijoSolver object"):
        fo.save_model(fo.FactIRL(solver=fo.SolverSettings(d_solver=solvers.ArmijoSolver())), tmp_path / "x.npz")
    with pytest.raises(PersistenceError, match="objective given as a PolicyMatchingObjective object.*register_objective"):
        fo.save_model(fo.GradIRL(objective=PolicyMatchingObjective), tmp_path / "x.npz")
    with pytest.raises(ValidationError, match="h_solver_options must hold plain values"):  # nothing to save: refused at once
        fo.GradIRL(solver=fo.SolverSettings("armijo", {"callback": print}))
    with pytest.raises(PersistenceError, match="cannot save rng of type RandomState"):
        fo.save_model(fo.FactIRL(rng=np.random.RandomState(0)), tmp_path / "x.npz")
    with pytest.raises(PersistenceError, match="init a tuple of length 3"):
        fo.save_model(fo.FactIRL(start=fo.Start(init=(1, 2, 3))), tmp_path / "x.npz")
    odd = fo.load_model(fo.save_model(fitted, tmp_path / "ok.npz"))
    odd.extra_ = object()
    with pytest.raises(PersistenceError, match="attribute extra_"):
        fo.save_model(odd, tmp_path / "x.npz")
    odd.extra_ = np.array([None])
    with pytest.raises(PersistenceError, match="extra_: it is an object array"):
        fo.save_model(odd, tmp_path / "x.npz")


@pytest.mark.parametrize(
    "demos, match",
    [
        ([], "demos_per_task is empty"),
        ("abc", "demos_per_task must be a list with one entry per task"),
        ([None], "task 0 must be an int array"),
        ([[]], "task 0 are empty"),
        ([[np.zeros((2, 3), int)]], r"demonstrations of task 0, episode 0 must have shape \(L, 2\)"),
        ([[[[0, 1], [2]]]], r"must be an array of \(state, action\) pairs"),
        ([[np.array([[0.5, 1.0]])]], r"task 0, episode 0, step 0: state 0.5 is not an integer"),
        ([[np.array([[0, 1]])], [np.array([[0, 0], [2, -1]])]], r"task 1, episode 0, step 1: action -1 is not a valid index"),
        ([np.array([[0, 1]]), np.array([[2, 3]])], r"demos_per_task\[0\] is a single episode"),
        ([["demos.npz"]], r"task 0, episode 0 is a file name"),
    ],
)
def test_save_demonstrations_validates(demos, match, tmp_path):
    with pytest.raises(ValidationError, match=match):
        fo.save_demonstrations(demos, tmp_path / "d.npz")


# ----------------------------------------------------------------------------- errors on load


@pytest.fixture()
def model_file(fitted, tmp_path):
    return fo.save_model(fitted, tmp_path / "model.npz")


@pytest.fixture()
def demos_file(setting, tmp_path):
    return fo.save_demonstrations([setting[2][0], list(setting[2][1])], tmp_path / "demos.npz")


def test_missing_file(tmp_path):
    for load in (fo.load_model, fo.load_demonstrations):
        with pytest.raises(PersistenceError, match=r"cannot read .*nope\.npz.*No such file or directory") as info:
            load(tmp_path / "nope.npz")
        assert isinstance(info.value.__cause__, FileNotFoundError)


def test_corrupt_and_foreign_files(model_file, tmp_path):
    cases = {
        "random.npz": np.random.default_rng(0).bytes(300),
        "empty.npz": b"",
        "text.npz": b"this is not an archive\n",
        "truncated.npz": open(model_file, "rb").read()[:200],
        "pickle.npz": pickle.dumps({"dictionary_": [1, 2]}),
    }
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
        with pytest.raises(PersistenceError, match="not a readable factirl-opt file"):
            fo.load_model(tmp_path / name)
        with pytest.raises(PersistenceError, match="not a readable factirl-opt file"):
            fo.load_demonstrations(tmp_path / name)
    np.save(tmp_path / "single.npy", np.arange(3))
    with pytest.raises(PersistenceError, match="single .npy array"):
        fo.load_model(tmp_path / "single.npy")
    np.savez(tmp_path / "plain.npz", a=np.arange(3))
    with pytest.raises(PersistenceError, match="no __header__ member"):
        fo.load_model(tmp_path / "plain.npz")
    np.savez(tmp_path / "objects.npz", __header__=np.array("{}"), a=np.array([None, 1], dtype=object))
    with pytest.raises(PersistenceError, match="not a readable factirl-opt file"):
        fo.load_model(tmp_path / "objects.npz")
    np.savez(tmp_path / "badjson.npz", __header__=np.array("{not json"))
    with pytest.raises(PersistenceError, match="not valid JSON"):
        fo.load_model(tmp_path / "badjson.npz")
    np.savez(tmp_path / "other.npz", __header__=np.array(json.dumps({"format": "something-else"})))
    with pytest.raises(PersistenceError, match="header does not say format 'factirl-opt'"):
        fo.load_model(tmp_path / "other.npz")


def test_format_versions(model_file, tmp_path):
    def future(h):
        h["format_version"] = FORMAT_VERSION + 1
        h["library_version"] = "9.0.0"

    with pytest.raises(PersistenceError, match=rf"format version {FORMAT_VERSION + 1}, written by factirl-opt 9.0.0.*upgrade"):
        fo.load_model(_rewrite(model_file, tmp_path / "future.npz", future))
    with pytest.raises(PersistenceError, match="format_version is missing"):
        fo.load_model(_rewrite(model_file, tmp_path / "nov.npz", lambda h: h.pop("format_version")))
    with pytest.raises(PersistenceError, match="format_version is missing or not an integer >= 1: '1'"):
        fo.load_model(_rewrite(model_file, tmp_path / "strv.npz", lambda h: h.update(format_version="1")))


def test_wrong_kind(model_file, demos_file):
    with pytest.raises(PersistenceError, match="holds 'model' data, not 'demonstrations'; use load_model"):
        fo.load_demonstrations(model_file)
    with pytest.raises(PersistenceError, match="holds 'demonstrations' data, not 'model'; use load_demonstrations"):
        fo.load_model(demos_file)


@pytest.mark.parametrize(
    "edit, drop, match",
    [
        (lambda h: h.pop("class"), (), "the header lacks 'class'"),
        (lambda h: h.pop("params"), (), "the header lacks 'params'"),
        (lambda h: h.pop("attributes"), (), "the header lacks 'attributes'"),
        (lambda h: h.pop("array_attributes"), (), "the header lacks 'array_attributes'"),
        (lambda h: h.pop("array_params"), (), "the header lacks 'array_params'"),
        (None, ("attr/dictionary_",), "the archive lacks 'attr/dictionary_'"),
        (lambda h: h.update({"class": "PCA"}), (), "unknown class 'PCA'"),
        (lambda h: h.update({"class": 3}), (), "'class' in the header must be a str"),
        (lambda h: h.update({"params": []}), (), "'params' in the header must be a dict"),
        (lambda h: h["params"].update({"n_components": 3}), (), "stored parameters do not fit FactIRL.*n_components"),
        (lambda h: h["params"].update({"rng": {"type": "generator", "bit_generator": "NoSuchBitGen"}}), (), "rng parameter is malformed"),
        (lambda h: h["params"].update({"rng": 7}), (), "rng parameter is malformed"),
        (lambda h: h["attributes"].update({"__class__": 1}), (), "'__class__' is not a learnt attribute of FactIRL"),
        (lambda h: h.update({"kind": None}), (), "holds None data, not 'model'"),
    ],
)
def test_incomplete_or_malformed_model_files(model_file, tmp_path, edit, drop, match):
    with pytest.raises(PersistenceError, match=match):
        fo.load_model(_rewrite(model_file, tmp_path / "bad.npz", edit, drop))


def test_missing_array_parameter(tmp_path):
    path = fo.save_model(fo.GradIRL(features=np.eye(64, 2)), tmp_path / "f.npz")
    with pytest.raises(PersistenceError, match="lacks 'param/features'"):
        fo.load_model(_rewrite(path, tmp_path / "bad.npz", drop=("param/features",)))
    path = fo.save_model(fo.FactIRL(start=fo.Start(init=(np.eye(64, 2), np.ones((3, 2))))), tmp_path / "t.npz")
    with pytest.raises(PersistenceError, match="lacks 'param/start__init/1'"):
        fo.load_model(_rewrite(path, tmp_path / "bad.npz", drop=("param/start__init/1",)))


@pytest.mark.parametrize(
    "edit, drop, extra, match",
    [
        (lambda h: h.pop("task_forms"), (), None, "the header lacks 'task_forms'"),
        (None, ("steps",), None, "the archive lacks 'steps'"),
        (None, ("episode_lengths",), None, "the archive lacks 'episode_lengths'"),
        (None, ("task_n_episodes",), None, "the archive lacks 'task_n_episodes'"),
        (None, (), {"steps": np.zeros((5, 2))}, "'steps' must be a 2-d integer array"),
        (None, (), {"episode_lengths": np.array([[3]])}, "'episode_lengths' must be a 1-d integer array"),
        (None, (), {"steps": np.zeros((5, 2), dtype=np.int64)}, "inconsistent"),
        (None, (), {"task_n_episodes": np.array([3, 2])}, "inconsistent"),
        (lambda h: h.update(task_forms=["array"]), (), None, "inconsistent"),
        (lambda h: h.update(task_forms=["array", "array"]), (), {"episode_lengths": np.array([6, 6, 6, 6, 8, 4])},
         r"task 1 has form 'array' with episode lengths \[6, 8, 4\]"),
        (lambda h: h.update(task_forms=["array", "tensor"]), (), None, "task 1 has form 'tensor'"),
    ],
)
def test_incomplete_or_inconsistent_demonstration_files(demos_file, tmp_path, edit, drop, extra, match):
    with pytest.raises(PersistenceError, match=match):
        fo.load_demonstrations(_rewrite(demos_file, tmp_path / "bad.npz", edit, drop, extra))


# ----------------------------------------------------------------------------- damaged members and contents


def _member_data_span(data, member):
    """Start and length of a member's (compressed) bytes inside a zip archive."""
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        info = z.getinfo(member)
    off = info.header_offset
    name_len, extra_len = struct.unpack("<HH", data[off + 26:off + 30])
    return off + 30 + name_len + extra_len, info.compress_size


@pytest.mark.parametrize("loader, member", [("model", "attr/dictionary_.npy"), ("demonstrations", "steps.npy")])
def test_corrupt_compressed_member_names_file_and_member(model_file, demos_file, tmp_path, loader, member):
    src = model_file if loader == "model" else demos_file
    data = bytearray(open(src, "rb").read())
    start, size = _member_data_span(bytes(data), member)
    data[start:start + size] = b"\xff" * size  # an invalid deflate block: zlib.error when decompressed
    bad = tmp_path / "corrupt.npz"
    bad.write_bytes(bytes(data))
    load = fo.load_model if loader == "model" else fo.load_demonstrations
    with pytest.raises(PersistenceError, match=rf"corrupt.npz is not a readable factirl-opt file: member '{member[:-4]}' is corrupt"):
        load(bad)


def test_truncated_files_at_every_tenth_byte(model_file, demos_file):
    for src, load in ((model_file, fo.load_model), (demos_file, fo.load_demonstrations)):
        data = open(src, "rb").read()
        for cut in range(0, len(data), max(1, len(data) // 40)):
            with pytest.raises(PersistenceError):
                load(io.BytesIO(data[:cut]))


def test_crafted_header_values(model_file, tmp_path):
    with pytest.raises(PersistenceError, match="format_version is missing or not an integer >= 1: 0"):
        fo.load_model(_rewrite(model_file, tmp_path / "v0.npz", lambda h: h.update(format_version=0)))
    with pytest.raises(PersistenceError, match="format_version is missing or not an integer >= 1: True"):
        fo.load_model(_rewrite(model_file, tmp_path / "vb.npz", lambda h: h.update(format_version=True)))
    np.savez(tmp_path / "list.npz", __header__=np.array(json.dumps([1, 2])))
    with pytest.raises(PersistenceError, match="header does not say format"):
        fo.load_model(tmp_path / "list.npz")
    np.savez(tmp_path / "deep.npz", __header__=np.array("[" * 100000 + "]" * 100000))
    with pytest.raises(PersistenceError, match="not valid JSON"):
        fo.load_model(tmp_path / "deep.npz")
    np.savez(tmp_path / "numeric.npz", __header__=np.arange(3))
    with pytest.raises(PersistenceError, match="not valid JSON"):
        fo.load_model(tmp_path / "numeric.npz")


@pytest.mark.parametrize(
    "edit, extra, match",
    [
        (lambda h: (h["attributes"].update(dictionary_="abc"), h["array_attributes"].remove("dictionary_")), None,
         "attribute dictionary_ must be a 2-d float array; got str 'abc'"),
        (lambda h: h["attributes"].update(dictionary_="abc"), None, "attribute dictionary_ is stored twice"),
        (lambda h: h["array_attributes"].append("extra_"), {"attr/extra_": np.ones(3)}, "'extra_' is not a learnt attribute of FactIRL"),
        (lambda h: h["attributes"].update(stop_reason_=3), None, "attribute stop_reason_ must be a string; got 3"),
        (lambda h: h["attributes"].update(n_iter_=[1]), None, "attribute n_iter_ must be an integer >= 0"),
        (None, {"attr/dictionary_": np.array(["abc"])}, r"attribute dictionary_ must be a 2-d float array; got <U3 of shape \(1,\)"),
        (None, {"attr/dictionary_": np.ones(64)}, r"attribute dictionary_ must be a 2-d float array; got float64 of shape \(64,\)"),
        (None, {"attr/dictionary_": np.ones((64, 2), dtype=np.int64)}, "attribute dictionary_ must be a 2-d float array; got int64"),
        (None, {"attr/dictionary_": np.full((64, 2), np.nan)}, r"attribute dictionary_ must be finite; found nan at index \(0, 0\)"),
        (None, {"attr/rewards_": np.full((5, 16, 4), np.inf)}, "attribute rewards_ must be finite; found inf"),
        (None, {"attr/coefficients_": np.ones((5, 3))}, r"coefficients_ of shape \(5, 3\) disagrees with axis 1 of dictionary_ \(shape \(64, 2\)\): axis 1 \(k\) has length 3, not 2"),
        (None, {"attr/loss_": np.ones(4)}, r"loss_ of shape \(4,\) disagrees with axis 0 of coefficients_ \(shape \(5, 2\)\): axis 0 \(n\) has length 4, not 5"),
        (lambda h: h["attributes"].update(n_iter_=-1), None, "attribute n_iter_ must be an integer >= 0; got -1"),
        (lambda h: h["attributes"].update(n_evaluations_="7"), None, "attribute n_evaluations_ must be an integer >= 0; got '7'"),
        (lambda h: h["attributes"].update(loss_history_=[1.0, "x"]), None, r"attribute loss_history_\[1\] must be a finite number"),
        (lambda h: h["attributes"].update(loss_history_=[1.0, float("nan")]), None, r"loss_history_\[1\] must be a finite number"),
        (lambda h: h["attributes"].update(loss_history_=3.0), None, "loss_history_ must be a list of finite numbers; got float"),
        (lambda h: h["array_attributes"].append(3), None, "array attribute names must be strings"),
        (lambda h: h["array_params"].append("beta"), None, "'beta' is not an array parameter"),
    ],
)
def test_crafted_model_contents(model_file, tmp_path, edit, extra, match):
    with pytest.raises(PersistenceError, match=match):
        fo.load_model(_rewrite(model_file, tmp_path / "crafted.npz", edit, extra=extra))


@pytest.mark.parametrize(
    "value, match",
    [
        (np.array([[1.0, np.inf]]), r"parameter features must be finite; found inf at index \(0, 1\)"),
        (np.array(["a", "b"]), "parameter features must be a 2-d numeric array; got <U1"),
        (np.ones(3), r"parameter features must be a 2-d numeric array; got float64 of shape \(3,\)"),
    ],
)
def test_crafted_array_parameters(tmp_path, value, match):
    path = fo.save_model(fo.GradIRL(features=np.eye(64, 2)), tmp_path / "f.npz")
    with pytest.raises(PersistenceError, match=match):
        fo.load_model(_rewrite(path, tmp_path / "bad.npz", extra={"param/features": value}))
    path = fo.save_model(fo.FactIRL(start=fo.Start(init=(np.eye(64, 2), np.ones((3, 2))))), tmp_path / "t.npz")
    with pytest.raises(PersistenceError, match=r"parameter start__init\[1\] must be"):
        fo.load_model(_rewrite(path, tmp_path / "bad.npz", extra={"param/start__init/1": np.array([np.nan])}))


def test_crafted_rng_cannot_call_other_numpy_functions(model_file, tmp_path):
    def crafted(h):
        h["params"]["rng"] = {"type": "generator", "bit_generator": "seed", "state": {}}

    with pytest.raises(PersistenceError, match="'seed' is not a numpy bit generator"):
        fo.load_model(_rewrite(model_file, tmp_path / "bad.npz", crafted))
    with pytest.raises(PersistenceError, match="rng parameter is malformed.*the seed must be an integer >= 0"):
        fo.load_model(_rewrite(model_file, tmp_path / "bad.npz", lambda h: h["params"].update(rng={"type": "seed", "value": "x"})))


def test_save_model_checks_learnt_attributes(fitted, tmp_path):
    odd = fo.load_model(fo.save_model(fitted, tmp_path / "ok.npz"))
    odd.dictionary_ = "abc"
    with pytest.raises(PersistenceError, match="cannot save FactIRL: attribute dictionary_ must be a 2-d float array"):
        fo.save_model(odd, tmp_path / "x.npz")
    odd.dictionary_ = np.full((64, 2), np.nan)
    with pytest.raises(PersistenceError, match="cannot save FactIRL: attribute dictionary_ must be finite"):
        fo.save_model(odd, tmp_path / "x.npz")


# ----------------------------------------------------------------------------- the MDP signature


def test_mdp_signature_round_trips_and_checks_the_mdp(setting, fitted, tmp_path):
    mdp = setting[0]
    model = fo.load_model(fo.save_model(fitted, tmp_path / "m.npz"))
    model.mdp_signature_ = mdp.signature()  # the learners record it at fit; set by hand here
    header, _ = _header(fo.save_model(model, tmp_path / "signed.npz"))
    assert header["attributes"]["mdp_signature_"] == mdp.signature()
    loaded = fo.load_model(tmp_path / "signed.npz")
    assert loaded.mdp_signature_ == mdp.signature()
    check_signature(loaded.mdp_signature_, mdp)
    with pytest.raises(ValidationError, match="fitted on another MDP"):
        check_signature(loaded.mdp_signature_, fo.GridWorld(size=4, gamma=0.8))


def test_files_without_signature_load_with_none(setting, fitted, tmp_path):
    path = fo.save_model(fitted, tmp_path / "m.npz")

    def version_1(h):
        h["format_version"] = 1
        h["attributes"].pop("mdp_signature_", None)

    old = fo.load_model(_rewrite(path, tmp_path / "v1.npz", version_1))
    assert old.mdp_signature_ is None
    np.testing.assert_array_equal(old.dictionary_, fitted.dictionary_)
    unfitted = fo.load_model(fo.save_model(fo.FactIRL(n_primitives=2), tmp_path / "u.npz"))
    assert not hasattr(unfitted, "mdp_signature_")


@pytest.mark.parametrize(
    "signature, match",
    [
        ({"n_states": 16}, "mdp_signature_ must be None or a dict with keys"),
        ("abc", "mdp_signature_ must be None or a dict"),
        ({"n_states": 0, "n_actions": 4, "gamma": 0.9, "transitions_sha256": "0" * 64}, "n_states must be an integer >= 1; got 0"),
        ({"n_states": 16, "n_actions": 4, "gamma": 1.5, "transitions_sha256": "0" * 64}, "gamma must be a finite number"),
        ({"n_states": 16, "n_actions": 4, "gamma": 0.9, "transitions_sha256": "xyz"}, "transitions_sha256 must be 64 hexadecimal digits"),
        ({"n_states": 32, "n_actions": 2, "gamma": 0.9, "transitions_sha256": "0" * 64},
         r"rewards_ of shape \(5, 16, 4\) disagrees with the MDP of mdp_signature_ \(S, A\) = \(32, 2\): axis 1 \(S\)"),
    ],
)
def test_malformed_signatures_are_refused(model_file, tmp_path, signature, match):
    with pytest.raises(PersistenceError, match=match):
        fo.load_model(_rewrite(model_file, tmp_path / "bad.npz", lambda h: h["attributes"].update(mdp_signature_=signature)))


# ----------------------------------------------------------------------------- demonstrations contents


@pytest.mark.parametrize(
    "dtype, column, value, match",
    [
        (np.int64, 0, -1, r"task 1, episode 1, step 2: state -1 is not a valid index"),
        (np.uint64, 1, 2**63, r"task 1, episode 1, step 2: action 9223372036854775808 is not a valid index"),
    ],
)
def test_negative_or_huge_states_in_a_file_are_refused(demos_file, tmp_path, dtype, column, value, match):
    # demos_file: task 0 an array (3, 6, 2), task 1 a list of 3 episodes of 6 steps; step 26 is task 1, episode 1, step 2
    _, arrays = _header(demos_file)
    assert arrays["episode_lengths"].tolist() == [6] * 6
    steps = arrays["steps"].astype(dtype)
    steps[26, column] = value
    with pytest.raises(PersistenceError, match=rf"bad.npz holds invalid demonstrations: demonstrations of {match}"):
        fo.load_demonstrations(_rewrite(demos_file, tmp_path / "bad.npz", extra={"steps": steps}))


def test_version_1_single_episode_task_loads_as_a_list(demos_file, tmp_path):
    def version_1(h):
        h["format_version"] = 1
        h["task_forms"] = ["episode", "list"]

    _, arrays = _header(demos_file)
    old = {"steps": arrays["steps"][:12], "episode_lengths": np.array([6, 6]), "task_n_episodes": np.array([1, 1])}
    back = fo.load_demonstrations(_rewrite(demos_file, tmp_path / "v1.npz", version_1, extra=old))
    assert isinstance(back[0], list) and len(back[0]) == 1 and back[0][0].shape == (6, 2)
    np.testing.assert_array_equal(back[0][0], arrays["steps"][:6])
    parse_demonstrations(back)  # accepted by the learners as it is


def test_inconsistent_lengths_cannot_overflow(demos_file, tmp_path):
    big = np.array([2**62, 2**62, 2**62, 2**62, 18, 18], dtype=np.int64)  # sums to 36 modulo 2**64
    with pytest.raises(PersistenceError, match="is inconsistent: 2 task forms, 2 tasks with 6 episodes, 6 episode lengths"):
        fo.load_demonstrations(_rewrite(demos_file, tmp_path / "bad.npz", extra={"episode_lengths": big}))


# ----------------------------------------------------------------------------- fuzzing


def _mutate(data, rng):
    buf = bytearray(data)
    op = rng.integers(3)
    if op == 0:  # flip a few bits
        for pos in rng.integers(0, len(buf), size=rng.integers(1, 4)):
            buf[pos] ^= 1 << int(rng.integers(8))
    elif op == 1:  # truncate
        del buf[rng.integers(0, len(buf)):]
    else:  # overwrite a run with random bytes
        pos = int(rng.integers(0, len(buf)))
        buf[pos:pos + int(rng.integers(1, 16))] = rng.bytes(int(rng.integers(1, 16)))
    return bytes(buf)


def _uncompressed(path):
    """The same file written with np.savez: the .npy headers and the JSON header in clear."""
    header, arrays = _header(path)
    buf = io.BytesIO()
    np.savez(buf, __header__=np.array(json.dumps(header)), **arrays)
    return buf.getvalue()


def _valid_model(model):
    assert type(model) in (fo.GradIRL, fo.FactIRL)
    for value in vars(model).values():
        if isinstance(value, np.ndarray) and value.dtype.kind == "f":
            assert np.all(np.isfinite(value))


def _valid_demos(demos):
    for task in parse_demonstrations(demos):
        assert task.steps.dtype == np.int64 and task.steps.min() >= 0


@pytest.mark.parametrize("kind", ["model", "demonstrations"])
@pytest.mark.parametrize("compressed", [True, False])
def test_fuzzed_files_load_or_raise_persistence_error(model_file, demos_file, kind, compressed):
    src, load, valid = (model_file, fo.load_model, _valid_model) if kind == "model" else (demos_file, fo.load_demonstrations, _valid_demos)
    data = open(src, "rb").read() if compressed else _uncompressed(src)
    rng = np.random.default_rng(2024)
    outcomes = {"refused": 0, "loaded": 0}
    with hang_guard(60):
        for _ in range(300):
            try:
                result = load(io.BytesIO(_mutate(data, rng)))
            except PersistenceError:
                outcomes["refused"] += 1
                continue
            valid(result)
            outcomes["loaded"] += 1
    assert outcomes["refused"] > 100  # most mutations damage the file, and every damage is reported
