"""Fingerprints of representative fits, to check a refactor leaves results bit for bit.

Each case fits a small model and records the SHA-256 of every learnt array (the bytes of
``np.ascontiguousarray(a)``), of the loss histories and of the counts. The cases span the
kinds of features (tabular, state rewards, shared features, per-task features on several
MDPs), the objectives (policy matching, MCE), the solvers (Armijo, L-BFGS, GN-QP; joint
scheme; constrained dictionary), the residual model, the flat model's transfer, sharded runs
(n_jobs=2), transfer with a per-call solver, the transfer posterior and the demonstration
requests, the sharing search (n_primitives="auto") and the multi-intention learner.

The estimators are built with the flat parameter names of the starting commit (deprecated
aliases afterwards, so this also checks they map onto the grouped parameters unchanged) and,
where the grouped parameters exist, a second time with them.

Usage (from the repository root):
    PYTHONPATH=$PWD python results/front-door/fingerprints.py OUT.json
    PYTHONPATH=$PWD python results/front-door/fingerprints.py OUT.json --compare BASE.json
"""

import argparse
import hashlib
import json
import sys
import warnings

import numpy as np

import factirl_opt as fo


def digest(value):
    if isinstance(value, (list, tuple)) and value and all(isinstance(v, np.ndarray) for v in value):
        return [digest(v) for v in value]
    a = np.ascontiguousarray(np.asarray(value, dtype=float))
    return f"{a.shape}:{hashlib.sha256(a.tobytes()).hexdigest()[:16]}"


def record(model, names):
    return {name: digest(getattr(model, name)) for name in names if hasattr(model, name)}


FACT = ["dictionary_", "coefficients_", "rewards_", "loss_", "loss_history_", "n_evaluations_", "n_iter_", "residuals_"]
TRANSFER = ["transfer_coefficients_", "transfer_rewards_", "transfer_loss_", "transfer_loss_history_",
            "transfer_n_evaluations_", "transfer_residuals_"]
FLAT = ["rewards_", "weights_", "loss_", "n_evaluations_", "n_iter_"]


def data(seed=0, n=6, size=4, m=2, L=6):
    rng = np.random.default_rng(seed)
    mdp = fo.GridWorld(size=size, p_success=0.7, gamma=0.9)
    S, A = mdp.n_states, mdp.n_actions
    D = rng.normal(size=(S * A, 2))
    R = (rng.normal(size=(n, 2)) @ D.T).reshape(n, S, A)
    demos = fo.sample_demonstrations(mdp, R, m, L, rng)
    new = fo.sample_demonstrations(mdp, R[:2] + 0.1, m, L, rng)
    features = rng.normal(size=(S * A, 5))
    return mdp, demos, new, features


def fact_case(kw, grouped, fit_kw=None, transfer_kw=None, posterior=False, starts=False, mdps=None):
    mdp, demos, new, features = data()
    kw = {k: (features if v == "FEATURES" else v) for k, v in kw.items()}
    grouped = None if grouped is None else {k: (features if v == "FEATURES" else v) for k, v in grouped.items()}
    out = {}
    for label, params in (("flat-names", kw), ("grouped", grouped)):
        if params is None:
            continue
        try:
            model = fo.FactIRL(**params)
        except TypeError as exc:  # the grouped names do not exist at the starting commit
            out[label] = f"unavailable: {exc}"
            continue
        m_fit = mdp if mdps is None else mdps(mdp, len(demos))
        model.fit(m_fit, demos, **(fit_kw or {}))
        rec = record(model, FACT)
        if transfer_kw is not None:
            tkw = dict(transfer_kw)
            if tkw.get("features") == "FEATURES":
                tkw["features"] = features
            m_new = mdp if mdps is None else mdps(mdp, len(new))
            model.transfer(m_new, new, **tkw)
            rec.update(record(model, TRANSFER))
            if posterior:
                post = model.transfer_posterior_
                rec["posterior"] = None if post is None else [[digest(p.mean), digest(p.covariance)] for p in post]
            if starts:
                rec["starts"] = [digest(s) for s in model.request_starts(m_new, new, n_requests=2)]
        if hasattr(model, "cv_results_"):
            rec["cv_results_"] = {k: digest(v) for k, v in model.cv_results_.items()
                                  if np.asarray(v).dtype.kind in "fiub"}
        out[label] = rec
    return out


def per_task_mdps(mdp, n):
    return [fo.GridWorld(size=4, p_success=0.7, gamma=0.9) if i % 2 else mdp for i in range(n)]


CASES = {
    "fact-tabular-pm-armijo": (dict(n_primitives=2, max_iter=5, rng=0),
                               dict(n_primitives=2, max_iter=5, rng=0), None, {}, True, True),
    "fact-random-init-lbfgs": (dict(n_primitives=2, max_iter=5, rng=1, init="random", solver="lbfgs", d_solver="lbfgs"),
                               dict(n_primitives=2, max_iter=5, rng=1, start=("start", dict(init="random")),
                                    solver=("solver", dict(h_solver="lbfgs", d_solver="lbfgs"))), None, {}, False, False),
    "fact-state-reward": (dict(n_primitives=2, max_iter=4, reward="state", flat_max_iter=20, pca_shrink=False),
                          dict(n_primitives=2, max_iter=4, reward="state",
                               start=("start", dict(flat_max_iter=20, pca_shrink=False))), None, {}, False, False),
    "fact-features-mce": (dict(n_primitives=2, max_iter=4, features="FEATURES", objective="mce", flat_tol=1e-3,
                               flat_stol=1e-5, transfer_max_iter=20),
                          dict(n_primitives=2, max_iter=4, features="FEATURES", objective="mce", transfer_max_iter=20,
                               start=("start", dict(flat_tol=1e-3, flat_stol=1e-5))), None, {}, True, True),
    "fact-per-task-features": (dict(n_primitives=2, max_iter=4, features="FEATURES", flat_solver="lbfgs"),
                               dict(n_primitives=2, max_iter=4, features="FEATURES",
                                    solver=("solver", dict(flat_solver="lbfgs"))),
                               None, {"features": "FEATURES"}, True, False, "per-task"),
    "fact-residual": (dict(n_primitives=2, max_iter=4, residual_penalty=1.0),
                      dict(n_primitives=2, max_iter=4, residual_penalty=1.0), None, {}, True, False),
    "fact-flat-model": (dict(n_primitives=2, max_iter=3, residual_penalty=0.0, flat_max_iter=30),
                        dict(n_primitives=2, max_iter=3, residual_penalty=0.0, start=("start", dict(flat_max_iter=30))),
                        None, {}, False, False),
    "fact-nonneg": (dict(n_primitives=2, max_iter=4, dictionary_constraint="nonneg"),
                    dict(n_primitives=2, max_iter=4, dictionary_constraint="nonneg"), None, {}, False, False),
    "fact-joint-lbfgs": (dict(n_primitives=2, max_iter=4, scheme="joint", d_solver="lbfgs", d_solver_options={"memory": 5}),
                         dict(n_primitives=2, max_iter=4, scheme="joint",
                              solver=("solver", dict(d_solver="lbfgs", d_solver_options={"memory": 5}))),
                         None, {}, False, False),
    "fact-gnqp-transfer-solver": (dict(n_primitives=2, max_iter=3, solver="gn-qp-clarabel", solver_options={}),
                                  dict(n_primitives=2, max_iter=3, solver=("solver", dict(h_solver="gn-qp-clarabel"))),
                                  None, {"solver": "lbfgs"}, False, False),
    "fact-sharded": (dict(n_primitives=2, max_iter=3, n_jobs=2, planner_options={"max_bytes": 10 ** 8}),
                     dict(n_primitives=2, max_iter=3,
                          execution=("execution", dict(n_jobs=2, planner_options={"max_bytes": 10 ** 8}))),
                     None, {}, True, False),
    "fact-auto": (dict(n_primitives="auto", max_iter=3, flat_max_iter=10, rng=0),
                  dict(n_primitives="auto", max_iter=3, rng=0, start=("start", dict(flat_max_iter=10))),
                  None, {}, False, False),
}

GROUPS = {"start": "Start", "solver": "SolverSettings", "execution": "Execution"}


def grouped_params(params):
    """The grouped form of a case's parameters: ``(group, fields)`` built as the group class, when it exists."""
    out = {}
    for k, v in params.items():
        if isinstance(v, tuple) and len(v) == 2 and v[0] in GROUPS:
            cls = getattr(fo, GROUPS[v[0]], None)
            if cls is None or (v[0] == "solver" and "flat_solver" not in getattr(cls, "__dataclass_fields__", {})):
                return None
            v = cls(**v[1])
        out[k] = v
    return out


def flat_cases():
    mdp, demos, new, features = data()
    out = {}
    for label, kw in (("flat-tabular", dict(max_iter=20)),
                      ("flat-features-mce-lbfgs", dict(features=features, objective="mce", solver="lbfgs", max_iter=15)),
                      ("flat-sharded", dict(max_iter=10, n_jobs=2))):
        out[label] = record(fo.GradIRL(**kw).fit(mdp, demos), FLAT)
    mi = fo.MultiIntentIRL(2, n_primitives=2, max_iter=3, m_step_max_iter=5, rng=0, n_init=1)
    mi.fit(mdp, [episode for task in demos for episode in task])
    out["multi-intent"] = {k: digest(v) for k, v in vars(mi).items()
                           if k.endswith("_") and isinstance(v, np.ndarray) and v.dtype.kind == "f"}
    return out


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("out")
    parser.add_argument("--compare")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    result = {}
    for name, (kw, grouped, fit_kw, transfer_kw, posterior, starts, *rest) in CASES.items():
        mdps = per_task_mdps if rest and rest[0] == "per-task" else None
        result[name] = fact_case(kw, grouped_params(grouped), fit_kw, transfer_kw, posterior, starts, mdps)
        print(name, "done", file=sys.stderr)
    result.update(flat_cases())
    with open(args.out, "w") as f:
        json.dump(result, f, indent=1, sort_keys=True)
    if args.compare:
        with open(args.compare) as f:
            base = json.load(f)
        bad = []
        for name, rec in base.items():
            if name not in result:
                bad.append(f"{name}: missing")
                continue
            ref = rec.get("flat-names", rec)
            for label in ("flat-names", "grouped"):
                got = result[name].get(label) if "flat-names" in rec else result[name]
                if got is None or isinstance(got, str):
                    continue
                if got != ref:
                    keys = [k for k in set(ref) | set(got) if ref.get(k) != got.get(k)]
                    bad.append(f"{name} [{label}]: differs in {sorted(keys)}")
                if "flat-names" not in rec:
                    break
        n_grouped = sum(isinstance(r, dict) and isinstance(r.get("grouped"), dict) for r in result.values())
        print(f"{len(base)} cases compared ({n_grouped} also with grouped parameters): "
              + ("all bit for bit" if not bad else "DIFFERENCES:\n" + "\n".join(bad)))
        sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
