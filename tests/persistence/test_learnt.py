"""The learnt attributes declared on the estimator classes drive what is saved and checked."""

import hashlib
import json

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import PersistenceError
from factirl_opt.persistence.learnt import KINDS, SIGNATURE_KEYS, features_sha256, is_array_kind
from factirl_opt.persistence.models import MODEL_CLASSES

CONFIGURATIONS = ["gradirl-tabular", "gradirl-features", "factirl-tabular", "factirl-features", "factirl-transfer",
                  "factirl-features-transfer"]


def _learnt(model):
    return {k: v for k, v in vars(model).items() if k.endswith("_") and not k.startswith("_")}


def _rewrite(src, dst, edit):
    with np.load(src, allow_pickle=False) as npz:
        header = json.loads(str(npz["__header__"][()]))
        arrays = {k: npz[k] for k in npz.files if k != "__header__"}
    edit(header, arrays)
    np.savez(dst, __header__=np.array(json.dumps(header)), **arrays)
    return dst


@pytest.mark.parametrize("cls", list(MODEL_CLASSES.values()))
def test_declarations_use_known_kinds(cls):
    assert cls.learnt_attributes, cls
    for key, kind in cls.learnt_attributes.items():
        assert key.endswith("_") and not key.startswith("_") and key.isidentifier(), key
        assert (is_array_kind(kind) and all(isinstance(a, str) for a in kind)) or kind in KINDS, (key, kind)


@pytest.mark.parametrize("name", CONFIGURATIONS)
def test_every_learnt_attribute_is_declared_and_round_trips(fitted_models, name, tmp_path):
    model = fitted_models[name]
    attributes = _learnt(model)
    declared = type(model).learnt_attributes
    assert set(attributes) <= set(declared), f"{name} sets undeclared attributes {set(attributes) - set(declared)}"
    assert {"rewards_", "loss_history_", "n_iter_", "status_", "mdp_signature_"} <= set(attributes)
    if name.endswith("transfer"):
        assert {"transfer_coefficients_", "transfer_rewards_", "transfer_loss_", "transfer_status_"} <= set(attributes)
    loaded = fo.load_model(fo.save_model(model, tmp_path / "m.npz"))
    assert set(_learnt(loaded)) == set(attributes) | {"features_sha256_"}
    S, A = model.mdp_signature_["n_states"], model.mdp_signature_["n_actions"]
    assert loaded.features_sha256_ == (None if model.features is None else features_sha256(model.features, S, A))
    for key, value in attributes.items():
        got = getattr(loaded, key)
        if isinstance(value, np.ndarray):
            assert got.dtype == value.dtype and got.shape == value.shape, key
            np.testing.assert_array_equal(got, value, err_msg=key)
        else:
            assert got == value and type(got) is type(value), key


def test_factirl_records_its_stop_reason_and_it_is_checked(fitted_models, tmp_path):
    model = fitted_models["factirl-tabular"]
    assert isinstance(model.stop_reason_, str) and model.stop_reason_
    path = fo.save_model(model, tmp_path / "m.npz")
    assert fo.load_model(path).stop_reason_ == model.stop_reason_
    bad = _rewrite(path, tmp_path / "bad.npz", lambda h, a: h["attributes"].update(stop_reason_=["x"]))
    with pytest.raises(PersistenceError, match=r"attribute stop_reason_ must be a string; got \['x'\]"):
        fo.load_model(bad)


def test_undeclared_attribute_is_refused_on_saving(fitted_models, tmp_path):
    model = fo.load_model(fo.save_model(fitted_models["gradirl-tabular"], tmp_path / "m.npz"))
    model.dictionary_ = np.eye(3)
    with pytest.raises(PersistenceError, match="cannot save GradIRL: 'dictionary_' is not a learnt attribute of GradIRL"):
        fo.save_model(model, tmp_path / "x.npz")
    assert not (tmp_path / "x.npz").exists()


@pytest.mark.parametrize(
    "key, value, match",
    [
        ("weights_", np.ones((4, 7)), r"weights_ of shape \(4, 7\) disagrees with the columns of the features parameter"),
        ("rewards_", np.ones((4, 16, 3)), r"rewards_ of shape \(4, 16, 3\) disagrees with the MDP .* axis 2 \(A\) has length 3, not 4"),
        ("loss_", np.ones(5), r"loss_ of shape \(5,\) disagrees with axis 0 of weights_"),
        ("loss_", np.ones((4, 1)), r"attribute loss_ must be a 1-d float array"),
        ("n_iter_", 2.0, "attribute n_iter_ must be an integer >= 0; got 2.0"),
        ("status_", np.array([1.0]), "attribute status_ must be a string; got an array of shape"),
        ("features_sha256_", "ABC", "attribute features_sha256_ must be None \\(no features\\) or the features' SHA-256"),
    ],
)
def test_saved_attributes_are_checked_by_kind(fitted_models, tmp_path, key, value, match):
    model = fo.load_model(fo.save_model(fitted_models["gradirl-features"], tmp_path / "m.npz"))
    setattr(model, key, value)
    with pytest.raises(PersistenceError, match=match):
        fo.save_model(model, tmp_path / "x.npz")


def test_files_without_the_new_attributes_still_load(fitted_models, grid_tasks, tmp_path):
    mdp, _, _, state_features, _ = grid_tasks
    model = fitted_models["factirl-features"]
    path = fo.save_model(model, tmp_path / "m.npz")

    def before_the_digest(header, arrays):
        header["attributes"].pop("stop_reason_", None)
        header["attributes"].pop("features_sha256_", None)

    old = fo.load_model(_rewrite(path, tmp_path / "old.npz", before_the_digest))
    assert not hasattr(old, "stop_reason_")
    assert old.features_sha256_ == features_sha256(state_features, mdp.n_states, mdp.n_actions)
    np.testing.assert_array_equal(old.dictionary_, model.dictionary_)

    def version_1(header, arrays):
        before_the_digest(header, arrays)
        header["format_version"] = 1
        header["attributes"].pop("mdp_signature_")

    oldest = fo.load_model(_rewrite(path, tmp_path / "v1.npz", version_1))
    assert oldest.mdp_signature_ is None  # S and A from rewards_: the state features are recognised
    assert oldest.features_sha256_ == features_sha256(state_features, mdp.n_states, mdp.n_actions)

    def without_rewards(header, arrays):
        version_1(header, arrays)
        header["array_attributes"].remove("rewards_")
        arrays.pop("attr/rewards_")

    assert fo.load_model(_rewrite(path, tmp_path / "v1r.npz", without_rewards)).features_sha256_ is None
    tabular = fo.load_model(_rewrite(fo.save_model(fitted_models["gradirl-tabular"], tmp_path / "t.npz"), tmp_path / "t1.npz",
                                     before_the_digest))
    assert tabular.features_sha256_ is None and tabular.mdp_signature_ == mdp.signature()
    unfitted = fo.load_model(fo.save_model(fo.GradIRL(), tmp_path / "u.npz"))
    assert not hasattr(unfitted, "features_sha256_") and not hasattr(unfitted, "mdp_signature_")


def test_features_digest_is_saved_and_checked_against_the_features(fitted_models, grid_tasks, tmp_path):
    mdp, _, _, state_features, _ = grid_tasks
    S, A = mdp.n_states, mdp.n_actions
    model = fo.load_model(fo.save_model(fitted_models["factirl-features"], tmp_path / "m.npz"))
    model.features_sha256_ = features_sha256(state_features, S, A)  # what the learners record at fit
    path = fo.save_model(model, tmp_path / "signed.npz")
    assert fo.load_model(path).features_sha256_ == features_sha256(state_features, S, A)

    other = state_features[::-1].copy()  # the same shape, other features
    assert features_sha256(other, S, A) != features_sha256(state_features, S, A)
    swapped = _rewrite(path, tmp_path / "swapped.npz", lambda h, a: a.update({"param/features": other}))
    with pytest.raises(PersistenceError, match="swapped.npz is malformed: the features parameter is not the one the model"):
        fo.load_model(swapped)
    model.features = other
    with pytest.raises(PersistenceError, match="cannot save FactIRL: the features parameter is not the one"):
        fo.save_model(model, tmp_path / "x.npz")
    model.features = np.ones((7, 5))
    with pytest.raises(PersistenceError, match=r"features parameter does not fit the model's MDP \(S, A\) = \(16, 4\): features must"):
        fo.save_model(model, tmp_path / "x.npz")
    model.features = np.ones((16, 3))  # the dictionary does not fit these either
    with pytest.raises(PersistenceError, match=r"dictionary_ of shape \(5, 2\) disagrees with the columns of the features"):
        fo.save_model(model, tmp_path / "x.npz")
    model.features = None
    with pytest.raises(PersistenceError, match="features_sha256_ records features, but the model has no features"):
        fo.save_model(model, tmp_path / "x.npz")
    bare = fo.FactIRL()
    bare.features_sha256_ = features_sha256(state_features, S, A)
    with pytest.raises(PersistenceError, match="features_sha256_ records features, but the model has no features"):
        fo.save_model(bare, tmp_path / "x.npz")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.npz", "signed.npz", "swapped.npz"]


def test_features_digest_definition():
    """SHA-256 of the features as the learners use them: float64 (S*A, p), repr of the shape, then the values."""
    S, A = 3, 2
    F = np.arange(12.0).reshape(S * A, 2)
    expected = hashlib.sha256(repr((S * A, 2)).encode() + F.tobytes()).hexdigest()
    assert features_sha256(F, S, A) == features_sha256(F.tolist(), S, A) == features_sha256(np.asfortranarray(F), S, A) == expected
    state = np.arange(6.0).reshape(S, 2)
    assert features_sha256(state, S, A) == features_sha256(np.repeat(state, A, axis=0), S, A)
    G = F.copy()
    G[2, 1] += 1e-12
    assert features_sha256(F, S, A) != features_sha256(G, S, A)


def test_signature_keys_are_the_mdps(grid_tasks):
    assert sorted(grid_tasks[0].signature()) == sorted(SIGNATURE_KEYS)


# ----------------------------------------------------------------------------- per-task arrays of different sizes


@pytest.fixture(scope="module")
def mixed_sizes(tmp_path_factory):
    """A FactIRL fitted on maps of 9, 16 and 9 states (per-task rewards and features), saved."""
    g3, g4 = fo.GridWorld(size=3, p_success=0.7, gamma=0.9), fo.GridWorld(size=4, p_success=0.8, gamma=0.9)
    mdps, rng = [g3, g4, g3], np.random.default_rng(0)
    Phis = [rng.random((9, 3)), rng.random((16 * 4, 3)), rng.random((9, 3))]
    demos = [fo.sample_demonstrations(m, rng.normal(size=(1, m.n_states, 4)), 2, 5, rng=i)[0] for i, m in enumerate(mdps)]
    model = fo.FactIRL(n_primitives=2, features=Phis, max_iter=1, flat_max_iter=1).fit(mdps, demos)
    return fo.save_model(model, tmp_path_factory.mktemp("mixed") / "model.npz")


def _set(key, value):
    return lambda header, arrays: arrays.__setitem__(key, value)


def _count(n):
    def edit(header, arrays):
        header["array_list_attributes"]["rewards_"] = n

    return edit


def _signature(task, n_states):
    def edit(header, arrays):
        header["attributes"]["mdp_signature_"][task]["n_states"] = n_states

    return edit


@pytest.mark.parametrize("edit, match", [
    (_set("attr/rewards_/1", np.zeros((9, 4))),
     r"attribute rewards_\[1\] of shape \(9, 4\) contradicts task 1's saved MDP signature in mdp_signature_: \(S, A\) = \(16, 4\)"),
    (_set("attr/rewards_/0", np.zeros((16, 4))), r"attribute rewards_\[0\] of shape \(16, 4\) contradicts task 0's saved MDP signature"),
    (_signature(1, 9), r"attribute rewards_\[1\] of shape \(16, 4\) contradicts task 1's saved MDP signature in mdp_signature_: "
                       r"\(S, A\) = \(9, 4\)"),
    (_count(2), r"attribute rewards_ of shape \(2, 0, 4\) disagrees with the 3 per-task MDP signatures"),
    (_set("attr/rewards_/3", np.zeros((9, 4))), "the archive holds attr/rewards_/3, which the header does not describe"),
    (_set("param/features/1", np.zeros((9, 3))), r"per-task features\[1\] of shape \(9, 3\) contradicts task 1's saved MDP "
                                                 r"signature in mdp_signature_ \(S, A\) = \(16, 4\): it needs S = 16 or S \* A = 64 rows"),
    (_set("param/features/2", np.zeros((9, 2))), r"per-task features\[2\] of shape \(9, 2\) must be a matrix with the 3 columns"),
])
def test_edited_per_task_arrays_contradicting_the_signatures_are_refused(mixed_sizes, tmp_path, edit, match):
    assert [r.shape for r in fo.load_model(mixed_sizes).rewards_] == [(9, 4), (16, 4), (9, 4)]
    with pytest.raises(PersistenceError, match="is malformed: " + match):
        fo.load_model(_rewrite(mixed_sizes, tmp_path / "edited.npz", edit))


def test_a_header_counting_more_per_task_arrays_than_stored_is_refused(mixed_sizes, tmp_path):
    with pytest.raises(PersistenceError, match="is incomplete: the archive lacks 'attr/rewards_/3'"):
        fo.load_model(_rewrite(mixed_sizes, tmp_path / "edited.npz", _count(4)))


@pytest.fixture(scope="module")
def searched_model_file(grid_tasks, tmp_path_factory):
    """A FactIRL whose k was searched (so it has a cv_results_), saved."""
    import warnings

    mdp, demos, _, state_features, _ = grid_tasks
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fo.exceptions.ConvergenceWarning)
        model = fo.FactIRL(n_primitives="auto", features=state_features, max_iter=2, rng=0,
                           sharing_search=fo.SharingSearch(route="race")).fit(mdp, demos)
    return fo.save_model(model, tmp_path_factory.mktemp("searched") / "searched.npz")


@pytest.mark.parametrize("column, entry, message", [
    ("mean_test_score", "0.5", r"cv_results_\['mean_test_score'\]\[0\] must be a finite number, or NaN .*; got '0.5'"),
    ("split0_test_score", None, r"cv_results_\['split0_test_score'\]\[0\] must be a finite number.*; got None"),
    ("std_test_score", True, r"cv_results_\['std_test_score'\]\[0\] must be a finite number.*; got True"),
    ("rank_test_score", 1.5, r"cv_results_\['rank_test_score'\]\[0\] must be an integer >= 0; got 1.5"),
    ("param_n_primitives", "2", r"cv_results_\['param_n_primitives'\]\[0\] must be an integer >= 0; got '2'"),
    ("param_residual_penalty", "inf", r"cv_results_\['param_residual_penalty'\]\[0\] must be a number >= 0"),
    ("chosen", "False", r"cv_results_\['chosen'\]\[0\] must be true or false; got 'False'"),
    ("params", "k=2", r"cv_results_\['params'\]\[0\] must be a dict"),
])
def test_a_stored_search_table_of_the_wrong_types_is_refused(searched_model_file, tmp_path, column, entry, message):
    """``load_model`` checks the types of ``cv_results_``'s entries, not only its keys and lengths: a
    string score used to load and fail later inside numpy (``plot_validation``)."""
    def edit(header, arrays):
        header["attributes"]["cv_results_"][column][0] = entry

    bad = _rewrite(searched_model_file, tmp_path / "bad.npz", edit)
    with pytest.raises(PersistenceError, match=message):
        fo.load_model(bad)
    loaded = fo.load_model(searched_model_file)  # the file as saved loads, its table of the saved types
    assert loaded.cv_results_["mean_test_score"].dtype == np.float64 and loaded.cv_results_["chosen"].dtype == bool
