"""The active benchmark: deviation after each added demonstration per start strategy, in a tiny configuration."""

import json

import numpy as np
import pytest

from factirl_opt.lab import bench


def run_bench(capsys, argv):
    assert bench.main(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_active_benchmark_quick_records_every_strategy_and_the_calibration(capsys):
    out = run_bench(capsys, ["active", "--quick", "--calibration", "--max-demos", "3"])
    row = out["worlds"]["grid"]["0"]
    assert set(row["strategies"]) == {"requested", "requested-value", "random", "entropy", "requested-regret",
                                      "requested-value-skip"}
    for st in row["strategies"].values():
        assert len(st["deviation"]) == len(st["map_deviation"]) == 3
        assert np.all(np.isfinite(st["deviation"])) and min(st["deviation"]) >= 0
        assert len(st["starts"]) == 2 and all(len(s) == row["n_test"] for s in st["starts"])
    cost = row["request_cost"]
    assert cost["request_over_transfer"] == pytest.approx(cost["request_cpu_s"] / cost["transfer_cpu_s"])
    cal = row["calibration"]
    assert 0 <= cal["coverage_90"] <= 1 and -1 <= cal["spearman"] <= 1 and cal["n_samples"] == 20


def test_active_benchmark_random_starts_depend_on_the_seed_only(capsys):
    argv = ["active", "--quick", "--strategies", "random", "--cost-repeats", "1"]
    a, b = run_bench(capsys, argv), run_bench(capsys, argv)
    assert a["worlds"]["grid"]["0"]["strategies"] == b["worlds"]["grid"]["0"]["strategies"]


@pytest.mark.parametrize("argv, fragment", [(["--worlds", "maze"], "invalid choice: 'maze'"),
                                            (["--max-demos", "0"], "--max-demos"),
                                            (["--strategies", "oracle"], "invalid choice: 'oracle'")])
def test_active_benchmark_options_are_checked_by_the_parser(capsys, argv, fragment):
    with pytest.raises(SystemExit):
        bench.build_parser().parse_args(["active", "--quick", *argv])
    assert fragment in capsys.readouterr().err


class _StubModel:
    """A fitted model for ``strategy_run`` whose transfers do nothing."""
    transfer_posterior_ = None

    def transfer(self, *a, **k):
        return self


class _StubTruth:
    """A ground truth for ``strategy_run``: ``n_tasks`` test tasks of one 3-step demonstration from state 0, zero rewards."""

    def __init__(self, n_tasks, mdp):
        self.test_demos = [np.zeros((1, 3, 2), dtype=int)] * n_tasks
        self.test_rewards = np.zeros((n_tasks, mdp.n_states, mdp.n_actions))


def test_active_benchmark_requested_strategies_pass_their_options(monkeypatch):
    from factirl_opt.lab.benchmarks import active

    seen = []

    def fake(model, mdp, demos, n_requests, **kw):
        seen.append(kw)
        return [np.array([0]) for _ in demos]

    monkeypatch.setattr(active, "request_starts", fake)
    monkeypatch.setattr(active, "_deviations", lambda *a: (np.zeros(1), np.zeros(1)))

    import factirl_opt as fo
    mdp = fo.GridWorld(size=2)
    s, gt = {"max_demos": 2}, _StubTruth(1, mdp)
    active.strategy_run(_StubModel(), gt, None, mdp, None, 1, "requested-value-skip", s, 0)
    active.strategy_run(_StubModel(), gt, None, mdp, None, 1, "requested-regret", s, 0, policy="greedy")
    active.strategy_run(_StubModel(), gt, None, mdp, None, 1, "requested", s, 0, criterion="value")
    assert [{k: v for k, v in kw.items() if k != "features"} for kw in seen] == [
        {"policy": "boltzmann", "criterion": "value", "demonstrated": "skip"},
        {"policy": "greedy", "criterion": "regret"},
        {"policy": "boltzmann", "criterion": "value"}]


def _recording_run(monkeypatch, strategy, start, n_tasks=2, max_demos=4):
    """strategy_run with every strategy's choice replaced by ``start``; the demonstrations each transfer sees."""
    import factirl_opt as fo
    from factirl_opt.lab.benchmarks import active

    monkeypatch.setattr(active, "request_starts", lambda model, mdp, demos, n, **kw: [np.array([start]) for _ in demos])
    monkeypatch.setattr(active, "policy_entropy_starts", lambda posts, *a, **kw: [np.array([start]) for _ in range(n_tasks)])
    monkeypatch.setattr(active, "_deviations", lambda *a: (np.zeros(1), np.zeros(1)))
    mdp = fo.GridWorld(size=4, p_success=0.5)
    rewards = np.random.default_rng(3).normal(size=(n_tasks, mdp.n_states, mdp.n_actions))

    class Model:
        transfer_posterior_ = None
        beta = 1.0

        def __init__(self):
            self.seen = []

        def transfer(self, mdp, demos, **kw):
            self.seen.append([d.copy() for d in demos])
            return self

    class GT:
        test_demos = fo.sample_demonstrations(mdp, rewards, 1, 6, rng=0)
        test_rewards = rewards

    model = Model()
    active.strategy_run(model, GT(), None, mdp, None, n_tasks, strategy, {"max_demos": max_demos}, 0)
    return model.seen


def test_active_benchmark_strategies_requesting_the_same_start_get_the_same_demonstrations(monkeypatch):
    # common random numbers: the transitions depend on (seed, task, step) only, not on the strategy
    seen = {st: _recording_run(monkeypatch, st, 5) for st in ("requested", "requested-regret", "entropy")}
    for st in ("requested-regret", "entropy"):
        assert len(seen[st]) == len(seen["requested"]) == 4
        for a, b in zip(seen["requested"], seen[st]):
            assert all(np.array_equal(x, y) for x, y in zip(a, b))
    last = seen["requested"][-1]
    assert all(d.shape[0] == 4 and np.all(d[1:, 0, 0] == 5) for d in last)
    # the draws differ between steps and tasks (p_success 0.5: a repeated stream would repeat the walk)
    walks = {tuple(d[j, :, 0]) for d in last for j in range(1, 4)}
    assert len(walks) > 1


def test_active_benchmark_demonstration_generator_depends_on_seed_task_and_step():
    from factirl_opt.lab.benchmarks.active import demonstration_rng

    draw = lambda *key: demonstration_rng(*key).random(4)  # noqa: E731
    assert np.array_equal(draw(0, 1, 2), draw(0, 1, 2))
    keys = [(0, 1, 2), (1, 1, 2), (0, 0, 2), (0, 1, 3)]
    assert len({tuple(draw(*k)) for k in keys}) == len(keys)


def test_active_benchmark_random_starts_come_from_start_rng(monkeypatch):
    from factirl_opt.lab.benchmarks import active

    monkeypatch.setattr(active, "sample_demonstrations", lambda mdp, r, m, L, rng, start: [np.zeros((1, L, 2), int)])
    monkeypatch.setattr(active, "_deviations", lambda *a: (np.zeros(1), np.zeros(1)))
    import factirl_opt as fo

    mdp, s = fo.GridWorld(size=4), {"max_demos": 6}
    run = lambda **kw: active.strategy_run(_StubModel(), _StubTruth(3, mdp), None, mdp, None, 3, "random", s, 0,  # noqa: E731
                                           **kw)["starts"]
    assert run() == run()
    assert run(start_rng=np.random.default_rng(7)) == run(start_rng=np.random.default_rng(7)) != run()


def test_active_benchmark_marginal_strategies_on_a_dictionary_ensemble(capsys):
    out = run_bench(capsys, ["active", "--quick", "--max-demos", "2", "--posterior-dictionaries", "2", "--transfer-stol", "1e-3",
                             "--strategies", "requested", "requested-marginal", "requested-marginal-noise", "--cost-repeats", "1"])
    assert out["settings"]["posterior_dictionaries"] == 2 and out["settings"]["transfer_stol"] == 1e-3
    strategies = out["worlds"]["grid"]["0"]["strategies"]
    assert set(strategies) == {"requested", "requested-marginal", "requested-marginal-noise"}
    assert all(np.all(np.isfinite(st["deviation"])) for st in strategies.values())


def test_active_benchmark_restores_the_models_posterior_noise(monkeypatch):
    import factirl_opt as fo
    from factirl_opt.lab.benchmarks import active

    seen = []

    class Model(_StubModel):
        posterior = None

        def set_params(self, **params):
            if "posterior__noise" in params:
                params = {"posterior": fo.PosteriorSettings(noise=params.pop("posterior__noise")), **params}
            vars(self).update(params)

    def fake(model, mdp, demos, n_requests, **kw):
        seen.append((model.posterior.noise, kw.get("marginal")))
        return [np.array([0]) for _ in demos]

    monkeypatch.setattr(active, "request_starts", fake)
    monkeypatch.setattr(active, "_deviations", lambda *a: (np.zeros(1), np.zeros(1)))
    mdp, model = fo.GridWorld(size=2), Model()
    active.strategy_run(model, _StubTruth(1, mdp), None, mdp, None, 1, "requested-marginal-noise", {"max_demos": 2}, 0)
    assert seen == [("misfit", True)] and model.posterior is None
