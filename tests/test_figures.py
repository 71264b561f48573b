"""One truth per figure: the figures the README, the guide and the command line's help quote are
those of the committed results they cite (each table cell and duration read back from its file)."""

import csv
import inspect
import json
import pathlib
import re

import factirl_opt as fo

ROOT = pathlib.Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def _summary(path):
    return list(csv.DictReader((ROOT / path).open()))


def _mean(rows, learner, n_tasks, demos=None, column="deviation_mean", split="test"):
    found = [float(r[column]) for r in rows if r["split"] == split and r["learner"] == learner
             and int(r["n_tasks"]) == n_tasks and (demos is None or int(r["demos_per_task"]) == demos)]
    assert len(found) == 1, (learner, n_tasks, demos, split, len(found))
    return found[0]


def _table(text, header_start):
    """The rows of the markdown table whose header line starts with ``header_start``: lists of cells."""
    lines = text[text.index(header_start):].splitlines()
    rows = []
    for line in lines[2:]:
        if not line.startswith("|"):
            break
        rows.append([c.strip() for c in line.strip("|").split("|")])
    return rows


def _numbers(cell):
    """The numbers of a cell such as ``**5.23** / 5.23`` (a dash is None)."""
    return [None if part.strip() == "-" else float(part.replace("*", "").strip()) for part in cell.split("/")]


def test_the_headline_table_is_the_paper_presets_summary():
    """The README's headline table: results/summary.csv at the paper's default point (100 tasks x 10 demos)."""
    rows = _summary("results/summary.csv")
    learners = ["flat", "factorial", "flat, PCA features", "flat, features from ex.", "flat, ground truth"]
    table = _table(README[README.index("<!-- headline: start -->"):], "| | flat | factorial")
    assert [r[0] for r in table] == ["train tasks", "test tasks (one demo)"]
    for (label, *cells), split in zip(table, ("train", "test")):
        for learner, cell in zip(learners, cells):
            (value,) = _numbers(cell)
            if value is not None:
                assert value == round(_mean(rows, learner, 100, 10, split=split), 2), (split, learner, cell)


#: the which-learner table's rows: (row label, preset directory, metric, learners' suffix, task counts)
WHICH_LEARNER_ROWS = {
    "paper grid, 5 training tasks": ("sharing-grid", "deviation_mean", "", (5,)),
    "paper grid, 20 training tasks": ("sharing-grid", "deviation_mean", "", (20,)),
    "paper grid, 100 training tasks": ("sharing-grid", "deviation_mean", "", (100,)),
    "Objectworld, a map per task, 5 / 20 tasks": ("sharing-objectworld-per-task-quick", "deviation_mean", ", features", (5, 20)),
    "Objectworld, one map, 5 / 20 tasks": ("sharing-objectworld-quick", "deviation_mean", ", features", (5, 20)),
    "BabyAI GoToLocal, 10 / 30 layouts (success)": ("sharing-babyai", "success_rate_mean", ", features", (10, 30)),
    "BabyAI GoToOpen, 10 layouts (success)": ("sharing-babyai-large", "success_rate_mean", ", features", (10,)),
}


def test_the_which_learner_table_is_the_benchmarks_summaries():
    """The README's table of the which-learner benchmark: each cell the mean of its preset's committed
    summary (results/which-learner/default/<preset>/summary.csv), flat, factorial and auto."""
    table = _table(README, "| benchmark | flat | factorial (k = 5) | auto |")
    assert {r[0] for r in table} == set(WHICH_LEARNER_ROWS)
    for label, *cells in table:
        preset, column, suffix, counts = WHICH_LEARNER_ROWS[label]
        rows = _summary(f"results/which-learner/default/{preset}/summary.csv")
        for learner, cell in zip(("flat", "factorial", "adaptive"), cells[:3]):
            values = _numbers(cell)
            assert len(values) == len(counts), (label, cell)
            for n, value in zip(counts, values):
                assert value == round(_mean(rows, learner + suffix, n, column=column), 2), (label, learner, n, cell)


def test_the_auto_cost_example_is_its_committed_run():
    """The README's cost of the default search on its ten-line grid: the CPU times and ratios of the
    two committed auto-cost runs (results/which-learner/default/auto-cost)."""
    runs = [json.loads((ROOT / "results/which-learner/default/auto-cost" / f).read_text())["seeds"]["0"]
            for f in ("readme-evidence-race-pca.json", "readme-evidence.json")]
    ratios = sorted(r["time_ratio"]["evidence"] for r in runs)
    assert f"costs {ratios[0]:.1f}-{ratios[1]:.1f}x the fixed" in README
    quoted = (f"{runs[0]['cpu_time_s']['evidence']:.1f} s against {runs[0]['cpu_time_s']['fixed']:.1f} s of CPU, and "
              f"{runs[1]['cpu_time_s']['evidence']:.1f} s against {runs[1]['cpu_time_s']['fixed']:.1f} s in a second run")
    assert quoted in " ".join(README.split())
    chosen = runs[0]["chosen"]
    assert (f"chooses k = {chosen['evidence']['n_primitives']}, lambda = {chosen['evidence']['residual_penalty']:g} and "
            f"transfers at {chosen['evidence']['test_deviation']:.2f} against k = 5's {runs[0]['fixed_test_deviation']:.2f}"
            in " ".join(README.split()))
    assert (f"costs {runs[0]['time_ratio']['race']:.1f}x there for ({chosen['race']['n_primitives']}, "
            f"{chosen['race']['residual_penalty']:g}), {chosen['race']['test_deviation']:.2f}" in " ".join(README.split()))


def test_the_paper_presets_duration_is_its_manifests_everywhere():
    """README, guide and the command line's preset description quote the committed run's wall time."""
    from factirl_opt.lab.experiments.presets import PRESET_DESCRIPTIONS

    minutes = round(json.loads((ROOT / "results/manifest.json").read_text())["wall_time_seconds"] / 60)
    guide = (ROOT / "docs/guide.md").read_text()
    results = (ROOT / "results/README.md").read_text()
    assert f"--out results   # {minutes} min on 2 busy cores (manifest.json)" in results
    for where, text in (("README", README), ("guide", guide), ("reproduce --list", PRESET_DESCRIPTIONS["paper"])):
        quoted = re.findall(r"(\d+) min(?:utes)?\b", " ".join(text.split()).split("--preset paper", 1)[-1][:400])
        assert quoted and int(quoted[0]) == minutes, (where, quoted, minutes)


def test_every_committed_claim_that_does_not_hold_gives_its_reason():
    """A "no" in a claims table carries its reason: the last column of every committed claims.md."""
    tables = sorted(ROOT.joinpath("results").rglob("claims.md"))
    assert len(tables) >= 20
    for path in tables:
        text = path.read_text()
        assert "| holds | seeds | why not |" in text, path
        for line in text.splitlines():
            if "| **no** |" in line:
                reason = line.rstrip().rstrip("|").rsplit("|", 1)[1].strip()
                assert len(reason) > 20, (path, line)


def _time_v(name):
    """Wall and CPU seconds of a ``/usr/bin/time -v`` record in results/setup."""
    text = (ROOT / "results/setup" / name).read_text()
    h_m_s = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): ([\d:.]+)", text).group(1).split(":")
    wall = sum(float(x) * 60 ** i for i, x in enumerate(reversed(h_m_s)))
    cpu = sum(float(re.search(rf"{kind} time \(seconds\): ([\d.]+)", text).group(1)) for kind in ("User", "System"))
    return wall, cpu


def _duration(seconds):
    """How the docs write a duration: ``27 s`` under a minute, ``3 min 27 s`` above."""
    seconds = round(seconds)
    return f"{seconds} s" if seconds < 60 else f"{seconds // 60} min {seconds % 60} s"


def test_the_set_up_commands_times_are_their_committed_measurements():
    """The README's and the development page's times of the two set-up commands: results/setup."""
    development = " ".join((ROOT / "docs/development.md").read_text().split())
    readme = " ".join(README.split())
    quick_wall, quick_cpu = _time_v("quick.time.txt")
    tests_wall, _ = _time_v("tests.time.txt")
    n_tests = int(re.search(r"(\d+) passed", (ROOT / "results/setup/tests-summary.txt").read_text()).group(1))
    for text in (readme, development):
        assert f"took {_duration(quick_wall)} of wall time ({_duration(quick_cpu)} of CPU time" in text
        assert f"took {_duration(tests_wall)} of wall time ({n_tests:,} tests" in text


def test_every_duration_the_command_line_quotes_is_a_committed_runs():
    """``factirl-opt reproduce --help``: a preset's duration cites the manifest of the run that took it."""
    from factirl_opt.lab.experiments.presets import PRESET_DESCRIPTIONS

    cited = 0
    for name, text in PRESET_DESCRIPTIONS.items():
        pattern = r"(\d+) (min|s) (?:of wall time )?with --jobs (\d+)[^():]*: (results/\S*manifest\.json)"
        for match in re.finditer(pattern, text):
            value, unit, jobs, path = match.groups()
            manifest = json.loads((ROOT / path).read_text())
            expected = manifest["wall_time_seconds"] / (60 if unit == "min" else 1)
            assert int(value) == round(expected) and int(jobs) == manifest["jobs"], (name, match.group(0))
            cited += 1
        bare = re.sub(pattern, "", text)
        assert not re.search(r"\d+(?:-\d+)? ?(?:s|min|minutes?|seconds?)\b", bare), (name, bare)  # no uncited duration
    assert cited >= 7


def test_the_guides_quick_reproduction_time_is_its_committed_run():
    guide = " ".join((ROOT / "docs/guide.md").read_text().split())
    seconds = round(json.loads((ROOT / "results/setup/quick-manifest.json").read_text())["wall_time_seconds"])
    assert f"its runs took {seconds} s of wall time in a fresh virtualenv, `results/setup/quick-manifest.json`" in guide
    results = " ".join((ROOT / "results/README.md").read_text().split())
    assert f"every learner and figure, {seconds} s (setup/quick-manifest.json)" in results
    assert f"took {seconds} s of wall time for its runs in a fresh virtualenv" in results


def test_the_which_learner_costs_and_the_fixed_k_example_are_the_benchmarks():
    """The README's cost of the default search over the benchmark (route_table.py on its records) and
    its example of a fixed k that transfers better (one Objectworld map, 20 tasks, seed 0)."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, str(ROOT / "results/which-learner/route_table.py"),
                          str(ROOT / "results/which-learner/default")], capture_output=True, text=True, check=True).stdout
    median, top = re.search(r"CPU-time ratio median ([\d.]+)x, max ([\d.]+)x", out).groups()
    whole_median, whole_top = re.search(r"flat start on both sides: median ([\d.]+)x, max ([\d.]+)x", out).groups()
    readme = " ".join(README.split())
    assert (f"costs a median {median}x the factorial fit's CPU time and at most {top}x ({whole_median}x and "
            f"{whole_top}x counting the flat start both fits pay)") in readme
    rows = [r for r in _summary("results/which-learner/default/sharing-objectworld-quick/results.csv")
            if r["split"] == "test" and r["seed"] == "0" and r["n_tasks"] == "20"]
    dev = {r["learner"]: float(r["deviation"]) for r in rows}
    assert f"k = 5 at {dev['factorial, features']:.2f} against {dev['adaptive, features']:.2f}" in readme


def _acceptance_draws():
    """The defaults on the acceptance draw against e87d706's default call: ``(row, e87d706's row)`` per
    seed and objective (results/defaults/walled_maps_panel_seed*.jsonl, e87d706's rows in walled_maps_switch_*)."""
    rows = [json.loads(line) for pattern in ("walled_maps_switch_seed*.jsonl", "walled_maps_panel_seed*.jsonl")
            for path in sorted((ROOT / "results/defaults").glob(pattern)) for line in path.read_text().splitlines()]
    ref = {(r["seed"], r["objective"]): r for r in rows if r["label"] == "e87d706"}
    now = [(r, ref[r["seed"], r["objective"]]) for r in rows if r["label"] == "panel1" and r["candidate"] == "defaults"]
    assert len(now) == 6
    return now


def test_the_defaults_figures_are_the_acceptance_draws():
    """The README's figures of the defaults: e87d706's default call against the defaults on the acceptance draw."""
    now = _acceptance_draws()
    cpu = sorted(r["cpu_s"] / e["cpu_s"] for r, e in now)
    test = max(r["mean_test_deviation"] / e["mean_test_deviation"] for r, e in now)
    train = max(r["mean_train_deviation"] / e["mean_train_deviation"] for r, e in now)
    readme = " ".join(README.split())
    assert (f"on per-task maps {cpu[0]:.2f}-{cpu[-1]:.2f}x the CPU of the paper's algorithm, test deviations within "
            f"{round(100 * (test - 1))}% and train deviations within {round(100 * (train - 1))}% of its on all 6 draws") in readme


def test_the_guides_route_table_on_the_readme_grid_is_the_auto_cost_runs():
    """The guide's table of routes, its README-grid column: the two committed auto-cost runs."""
    runs = [json.loads((ROOT / "results/which-learner/default/auto-cost" / f).read_text())["seeds"]["0"]
            for f in ("readme-evidence-race-pca.json", "readme-evidence.json")]
    guide = (ROOT / "docs/guide.md").read_text()
    rows = {r[0].strip("`").split('"')[1]: r for r in _table(guide, "| route | candidates | README grid")}
    ratios = sorted(r["time_ratio"]["evidence"] for r in runs)
    chosen, fixed = runs[0]["chosen"], runs[0]["fixed_test_deviation"]
    assert rows["evidence"][2] == (f"{ratios[0]:.1f}-{ratios[1]:.1f}x, chose ({chosen['evidence']['n_primitives']}, "
                                   f"{chosen['evidence']['residual_penalty']:g}): {chosen['evidence']['test_deviation']:.2f} "
                                   f"(k = 5: {fixed:.2f})")
    for route in ("race", "pca"):
        assert rows[route][2] == (f"{runs[0]['time_ratio'][route]:.1f}x, chose ({chosen[route]['n_primitives']}, "
                                  f"{chosen[route]['residual_penalty']:g}): {chosen[route]['test_deviation']:.2f}")


# --- the user guide (docs/getting-started.md includes its first sections) and the README's prose ---

GUIDE = (ROOT / "docs/guide.md").read_text()


def _flat(text):
    """The text with its line breaks and runs of spaces made single spaces (how phrases are matched)."""
    return " ".join(text.split())


def _json(path):
    return json.loads((ROOT / path).read_text())


def _agrees(quoted, value):
    """Whether the number as the text writes it (``"0.0601"``, ``"416"``, ``"16.5"``) is ``value`` at the
    text's rounding: as many decimals as the text shows."""
    decimals = len(quoted.split(".")[1]) if "." in quoted else 0
    return float(quoted) == round(value, decimals)


def _quoted(text, pattern):
    """The groups of the one place ``pattern`` (a regular expression) matches the whitespace-normalised text."""
    found = re.findall(pattern, _flat(text))
    assert len(found) == 1, (pattern, found)
    return found[0]


def test_the_guides_solver_table_and_figures_are_the_solvers_benchmark():
    """"Choosing a solver": the transfer table, the QP's cost, the fit, nonneg and sparse figures of
    ``bench solvers`` (results/solvers/bench.json)."""
    bench = _json("results/solvers/bench.json")
    transfer = bench["transfer"]["solvers"]
    rows = {r[0].split("`")[1]: r[1:] for r in _table(GUIDE, "| transfer | loss per task | Q* evaluations")}
    assert set(rows) == {"armijo", "gn-qp-osqp", "gn-qp-clarabel"}
    for name, (loss, evaluations, wall, dev) in rows.items():
        got = transfer[name]
        assert _agrees(loss, got["final_loss_per_task"]) and int(evaluations) == got["q_evaluations"], (name, loss, evaluations)
        assert _agrees(wall.removesuffix(" s"), got["wall_time_s"]) and _agrees(dev, got["mean_deviation"]), (name, wall, dev)
    qp = [route["cvxpy_block_dpp_per_task_us"] for key, route in bench["subproblem_timing"]["routes"].items()
          if key.startswith("none/")]
    assert f"the unconstrained QP itself costs {round(min(qp))}-{round(max(qp))} us per task" in _flat(GUIDE)
    fit = bench["fit"]["solvers"]
    assert (f"The proximal form: loss {fit['gn-qp-clarabel']['final_loss']:.3f} vs {fit['armijo']['final_loss']:.3f} in "
            f"{fit['gn-qp-clarabel']['q_evaluations']} vs {fit['armijo']['q_evaluations']} Q* evaluations") in _flat(GUIDE)
    nonneg = bench["nonneg"]["solvers"]
    assert nonneg["gn-qp-clarabel-nonneg"]["min_coefficient"] >= 0
    ratio = nonneg["gn-qp-clarabel-nonneg"]["mean_deviation"] / nonneg["gn-qp-clarabel"]["mean_deviation"]
    assert f"all coefficients >= 0 and {ratio:.2f}x the unconstrained deviation" in _flat(GUIDE)
    zeros, alphas = _quoted(GUIDE, r"`gn-qp-osqp-sparse` gave ([\d, ]+) exact zeros of 250 for alpha ([\d.]+(?:, [\d.]+)*)\.")
    sweep = {run["alpha"]: run["exact_zeros"] for run in bench["sparse"]["variants"]["gn-qp-osqp-sparse"]["sweep"]}
    assert bench["sparse"]["setting"]["coefficients_total"] == 250
    assert [int(z) for z in zeros.split(", ")] == [sweep[float(a)] for a in alphas.split(", ")]
    gn, armijo = transfer["gn-qp-clarabel"]["q_evaluations"], transfer["armijo"]["q_evaluations"]
    assert f"({gn} evaluations for {transfer['gn-qp-clarabel']['iterations']} steps above)" in _flat(GUIDE)
    performance = _flat((ROOT / "docs/performance.md").read_text())
    assert (f"the QP H-steps reach loss {transfer['gn-qp-clarabel']['final_loss_per_task']:.2g} per task in {gn} evaluations "
            f"where 100 Armijo iterations reach {transfer['armijo']['final_loss_per_task']:.3f} in {armijo}") in performance
    assert f"transfer in {gn} evaluations where Armijo takes {armijo} for policy matching" in _flat(GUIDE)


def _claim(path, name, point):
    """(holds, seeds) of the claim ``name`` at ``point`` in a committed claims.md: ``("yes", "3/3")``."""
    for line in (ROOT / path).read_text().splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if len(cells) > 5 and cells[0] == name and cells[2] == point:
            return cells[4].strip("*"), cells[5]
    raise AssertionError((path, name, point))


def _cells(rows, column, split, learner, n_tasks=100, demos=10):
    return [float(r[column]) for r in rows if r["split"] == split and r["learner"] == learner
            and int(r["n_tasks"]) == n_tasks and int(r["demos_per_task"]) == demos]


def test_the_guides_three_seed_mce_figures_are_the_fast_mce_run():
    """"Choosing an objective", three seeds: results/fast-mce's summary, evaluations, wall times, claims
    and manifest at the default point (100 tasks x 10 demos)."""
    import statistics

    text = _flat(GUIDE)
    minutes, seconds = divmod(round(_json("results/fast-mce/manifest.json")["wall_time_seconds"]), 60)
    assert f"--lineup paper+mce --jobs 2`, {minutes} min {seconds} s beside other jobs" in text
    summary = _summary("results/fast-mce/summary.csv")
    means = {(split, learner): _mean(summary, learner, 100, 10, split=split)
             for split in ("train", "test") for learner in ("flat", "flat MCE", "factorial", "factorial MCE")}
    quoted = (f"flat train {means['train', 'flat']:.2f} (policy matching) vs {means['train', 'flat MCE']:.2f} (MCE), "
              f"factorial train {means['train', 'factorial']:.2f} vs {means['train', 'factorial MCE']:.2f}, flat test "
              f"{means['test', 'flat']:.2f} vs {means['test', 'flat MCE']:.2f}, factorial transfer "
              f"{means['test', 'factorial']:.2f} vs {means['test', 'factorial MCE']:.2f}")
    assert quoted in text
    for split in ("train", "test"):
        assert _claim("results/fast-mce/claims.md", f"{split}: factorial MCE beats flat MCE", "100 tasks, 10 demos") == ("yes", "3/3")
    sweeps = {"demos": ("100 tasks, 1 demos", "100 tasks, 2 demos", "100 tasks, 5 demos", "100 tasks, 20 demos"),
              "tasks": ("5 tasks, 10 demos", "10 tasks, 10 demos", "20 tasks, 10 demos", "50 tasks, 10 demos")}
    fails = {point for sweep, points in sweeps.items() for point in points
             if _claim("results/fast-mce/claims.md", f"test: factorial MCE beats flat MCE ({sweep} sweep)", point)[0] == "no"}
    assert fails == {"100 tasks, 1 demos", "100 tasks, 2 demos", "5 tasks, 10 demos", "10 tasks, 10 demos"}  # "1-2 demonstrations or 5-10 training tasks"
    assert "fails where the policy-matching factorial learner fails (1-2 demonstrations or 5-10 training tasks)" in text
    results, timings = _summary("results/fast-mce/results.csv"), _summary("results/fast-mce/timings.csv")
    evaluations = {learner: statistics.mean(_cells(results, "n_evaluations", "train", learner)) for learner in ("flat", "flat MCE")}
    wall = {learner: statistics.median(_cells(timings, "fit_time", "train", learner))
            for learner in ("flat", "flat MCE", "factorial", "factorial MCE")}
    assert (f"the flat MCE fit took {evaluations['flat MCE'] / evaluations['flat']:.1f}x the evaluations "
            f"({evaluations['flat MCE']:.0f} vs {evaluations['flat']:.0f}) and {wall['flat MCE'] / wall['flat']:.1f}x the wall "
            f"time ({wall['flat MCE']:.1f} s vs {wall['flat']:.1f} s per 100 tasks") in text
    assert f"time ({wall['factorial MCE']:.1f} s vs {wall['factorial']:.1f} s, MCE with L-BFGS H-steps" in text


def test_the_guides_objectworld_mce_figures_are_its_committed_runs():
    """results/objectworld-mce's summary and claims, and the CPU ratio of results/mce-speed's three fits."""
    import statistics

    text = _flat(GUIDE)
    rows = _summary("results/objectworld-mce/summary.csv")
    dev = {(split, learner): _mean(rows, learner, 100, 32, split=split) for split in ("train", "test")
           for learner in ("factorial MCE, features", "factorial, features", "flat MCE, features")}
    assert (f"factorial on features train {dev['train', 'factorial MCE, features']:.2f} vs {dev['train', 'factorial, features']:.2f}, "
            f"test transfer {dev['test', 'factorial MCE, features']:.2f} vs {dev['test', 'factorial, features']:.2f}") in text
    holds, seeds = _claim("results/objectworld-mce/claims.md", "test: factorial MCE, features beats flat MCE, features",
                          "100 tasks, 32 demos")
    assert holds == "yes"
    assert (f"factorial MCE beats flat MCE (test {dev['test', 'factorial MCE, features']:.2f} vs "
            f"{dev['test', 'flat MCE, features']:.2f}, {seeds} seeds)") in text
    fits = _json("results/mce-speed/final_30_tasks_repeats3.json")["fits"]
    median = statistics.median(fits["mce"]["cpus_s"]) / statistics.median(fits["policy-matching"]["cpus_s"])
    fastest = min(fits["mce"]["cpus_s"]) / min(fits["policy-matching"]["cpus_s"])
    assert f"at {median:.2f}-{fastest:.2f}x the CPU time of policy matching" in text


def test_the_guides_model_error_figures_are_the_robustness_run():
    """"When the model is not given": the factorial learner's losses with estimated models,
    results/robustness/summary.csv (M = 0: the demonstrations alone; 100000 exploration transitions)."""
    rows = {(r["M"], r["learner"], r["split"]): float(r["deviation_mean"]) for r in _summary("results/robustness/summary.csv")}

    def loss(m, split):
        return round(100 * (rows[m, "factorial", split] / rows["true", "factorial", split] - 1))

    assert loss("100000", "train") <= 0  # "nothing on its training tasks"
    assert (f"loses {loss('0', 'train')}% on its training tasks ({rows['0', 'factorial', 'train']:.2f} against "
            f"{rows['true', 'factorial', 'train']:.2f}) and {loss('0', 'test')}% on transfer with the model from the "
            f"demonstrations alone; at 10^5, nothing on its training tasks and {loss('100000', 'test')}% on transfer") in _flat(GUIDE)
    worst = {split: max(v for (m, learner, s), v in rows.items() if learner == "factorial" and s == split and m != "true")
             for split in ("train", "test")}
    times = {split: round(rows["true", "flat", split] / worst[split]) for split in ("train", "test")}
    assert f"stays {times['train']}x (train) and {times['test']}x (transfer) better than the flat learner" in _flat(GUIDE)


def test_the_guides_unlabeled_figures_are_the_unlabeled_run():
    """"What to expect" of EM: results/unlabeled/tasks_8_seeds_100-104.json (the adjusted Rand indices'
    ranges over the 5 seeds, the likelihood comparison) and the README's record of the start tried."""
    rows = _json("results/unlabeled/tasks_8_seeds_100-104.json")["rows"]

    def span(key):
        values = [r["oracle_ari"] if key == "oracle" else r["learners"][key]["ari"] for r in rows]
        return f"{min(values):.2f}-{max(values):.2f}"

    text = _flat(GUIDE)
    assert f"adjusted Rand index of {span('em_shared')}, although the true rewards would assign" in text
    assert f"tasks at {span('oracle')} (table in `results/unlabeled/`" in text
    higher = sum(r["learners"]["em_shared"]["best_log_likelihood"] > r["learners"]["em_shared_true_start"]["best_log_likelihood"]
                 for r in rows)
    assert (f"the shared EM drifts to {span('em_shared_true_start')} while the default start, at {span('em_shared')}, "
            f"reaches a higher likelihood on {higher} seeds of {len(rows)}") in text
    assert f"the true one gives EM {span('em_true_dictionary')}" in text
    assert f"from the same episodes only {span('em_labelled_dictionary')}" in text
    readme = _flat((ROOT / "results/unlabeled/README.md").read_text())
    fixed, clustered = _quoted(GUIDE, r"FactIRL's dictionary then gives EM ([\d.]+ and [\d.]+), and clustering its coefficients ([\d.]+)\)")
    assert f"its dictionary held fixed in EM ({fixed.replace(' and', ',')})" in readme
    assert f"its coefficients clustered (ARI {clustered})" in readme


def test_the_guides_regret_bound_coverage_is_the_active_run():
    """The transfer posterior's 90% bound: its coverage per seed on the paper grid, results/active/grid.json."""
    coverage = [run["calibration"]["coverage_90"] for run in _json("results/active/grid.json")["worlds"]["grid"].values()]
    assert len(coverage) == 3
    assert f"a 90% upper bound, which covered {round(100 * min(coverage))}-{round(100 * max(coverage))}% of the paper grid's test tasks" in _flat(GUIDE)


def test_the_guides_objective_table_is_its_committed_run():
    """"Choosing an objective": the table and the trade-offs read from
    results/objectives/objectives_table.json (policy matching against MCE, one seed)."""
    runs = _json("results/objectives/objectives_table.json")["objectives"]
    pm, mce = runs["policy-matching"], runs["mce"]
    table = {r[0]: r[1:] for r in _table(GUIDE, "| | policy matching | MCE |")}
    for label, key in (("flat, train tasks", "flat_train_deviation"), ("factorial, train tasks", "factorial_train_deviation"),
                       ("flat, test tasks (one demonstration, from scratch)", "flat_test_deviation"),
                       ("factorial, test tasks (transfer, dictionary fixed)", "factorial_test_deviation")):
        assert all(_agrees(cell, run[key]) for cell, run in zip(table[label], (pm, mce))), (label, table[label])
    for label, key in (("flat fit: planning evaluations / CPU time", "flat_fit"),
                       ("factorial fit: planning evaluations / CPU time", "factorial_fit")):
        for cell, run in zip(table[label], (pm, mce)):
            evaluations, cpu = cell.removesuffix(" s").split(" / ")
            assert int(evaluations) == run[key]["evaluations"] and _agrees(cpu, run[key]["cpu_s"]), (label, cell)
    assert all(run["factorial_fit"]["stop_reason"].startswith("gradient norm") for run in (pm, mce))
    ahead = [round(100 * (1 - mce[key] / pm[key])) for key in
             ("flat_train_deviation", "factorial_train_deviation", "flat_test_deviation", "factorial_test_deviation")]
    text = _flat(GUIDE)
    assert f"({ahead[0]}% on flat train tasks, {ahead[1]}% factorial train, {ahead[2]}% flat test, {ahead[3]}% factorial transfer" in text
    train = sorted(run["flat_train_deviation"] / run["factorial_train_deviation"] for run in (pm, mce))
    test = [run["flat_test_deviation"] / run["factorial_test_deviation"] for run in (pm, mce)]
    assert (f"on training tasks ({train[0]:.1f}-{train[1]:.1f}x) and on new tasks from one demonstration "
            f"({test[0]:.1f}x and {test[1]:.1f}x)") in text
    per_evaluation = (mce["flat_fit"]["cpu_s"] / mce["flat_fit"]["evaluations"]) / (pm["flat_fit"]["cpu_s"] / pm["flat_fit"]["evaluations"])
    assert (f"an evaluation of the flat fit cost {per_evaluation:.1f}x policy matching's CPU time "
            f"({mce['flat_fit']['cpu_s']:.1f} s for {mce['flat_fit']['evaluations']} against {pm['flat_fit']['cpu_s']:.1f} s "
            f"for {pm['flat_fit']['evaluations']})") in text
    assert (f"The factorial MCE fit stopped after {mce['factorial_fit']['evaluations']} evaluations and policy matching's "
            f"after {pm['factorial_fit']['evaluations']}, and it took {mce['factorial_fit']['cpu_s'] / pm['factorial_fit']['cpu_s']:.1f}x "
            f"the CPU time ({mce['factorial_fit']['cpu_s']:.1f} s vs {pm['factorial_fit']['cpu_s']:.1f} s") in text


def _route_table(out):
    """(pairs no worse, pairs, median CPU ratio, max ratio) of route_table.py's summary of a which-learner run."""
    import subprocess
    import sys

    text = subprocess.run([sys.executable, str(ROOT / "results/which-learner/route_table.py"), str(ROOT / out)],
                          capture_output=True, text=True, check=True).stdout
    return re.search(r"no worse on (\d+) of (\d+) pairs; CPU-time ratio median ([\d.]+)x, max ([\d.]+)x", text).groups()


def _route_pairs(out):
    """route_table.py's pairs of a which-learner run directory (its preset, point, seed, scores, verdict, choice)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("route_table", ROOT / "results/which-learner/route_table.py")
    route_table = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(route_table)
    return list(route_table.pairs(ROOT / out))


def _race_pairs():
    """The race's (the former default route's) 30 run records, results/which-learner/runs/<preset>/*.json:
    (preset, n_tasks, seed, no worse, wall-time ratio of the adaptive training fit over the factorial one)."""
    margins = {"deviation": 0.10, "success_rate": 0.05}  # the benchmark's (claims.SHARING_MARGINS)
    for path in sorted((ROOT / "results/which-learner/runs").glob("*/*.json")):
        rec = json.loads(path.read_text())
        wall = {t["learner"].split(",")[0]: t["fit_time"] for t in rec["timings"] if t["split"] == "train"}
        test = [r for r in rec["rows"] if r["split"] == "test"]
        column = "success_rate" if "success_rate" in test[0] else "deviation"
        score = {r["learner"].split(",")[0]: r[column] for r in test}
        if column == "deviation":
            ok = score["adaptive"] <= (1 + margins[column]) * min(score["flat"], score["factorial"])
        else:
            ok = score["adaptive"] >= max(score["flat"], score["factorial"]) - margins[column]
        yield rec["preset"]["name"], rec["spec"]["n_tasks"], rec["spec"]["seed"], ok, wall["adaptive"] / wall["factorial"]


def test_the_guides_route_table_is_the_routes_committed_runs():
    """The guide's table of search routes beyond its README-grid column: the tiny grid's auto-cost runs,
    the routes' whole-benchmark runs (route_table.py; the race's wall times) and the earlier routes'
    table (results/which-learner/README.md)."""
    import statistics

    rows = {r[0].strip("`").split('"')[1]: r for r in _table(GUIDE, "| route | candidates | README grid")}
    tiny = _json("results/which-learner/default/auto-cost/tiny-evidence-race.json")["seeds"]
    for route in ("evidence", "race"):
        assert rows[route][3] == f"{tiny['0']['time_ratio'][route]:.1f}x / {tiny['1']['time_ratio'][route]:.1f}x", route
    earlier = {r[0]: r for r in _table((ROOT / "results/which-learner/README.md").read_text(), "| point (seed 0) | factorial")}
    assert rows["pca"][3] == earlier["`tiny`, seeds 0 / 1 (`auto-cost`)"][3].removeprefix("(1, 0), ") + " (2026-11-27)"
    assert rows["short"][3] == earlier["`tiny`, seeds 0 / 1 (`auto-cost`)"][4].removeprefix("(1, 0), ") + " (2026-11-27)"
    k, lam, dev, cost = re.match(r"\((\d+), (\d+)\) ([\d.]+), ([\d.]+x)", earlier["README grid, 30 tasks (`--readme`)"][4]).groups()
    assert rows["short"][2] == f"{cost}, chose ({k}, {lam}): {dev} (2026-11-27)"
    for route, out in (("evidence", "results/which-learner/default"), ("pca", "results/which-learner/route-pca")):
        no_worse, pairs, median, top = _route_table(out)
        assert pairs == "30" and rows[route][4].startswith(f"median {median}x, at most {top}x; {no_worse} ("), (route, rows[route][4])
    race = list(_race_pairs())
    ratios = [ratio for *_, ratio in race]
    no_worse = sum(ok for _, _, _, ok, _ in race)
    assert len(race) == 30
    assert rows["race"][4].startswith(f"median {statistics.median(ratios):.0f}x of wall time, "
                                      f"{min(ratios):.0f}-{max(ratios):.0f}x; {no_worse} (")
    assert {(p, n, s) for p, n, s, ok, _ in race if not ok} == {
        ("sharing-grid", 100, 0), ("sharing-objectworld-quick", 20, 0), ("sharing-objectworld-quick", 20, 1),
        ("sharing-babyai", 30, 1)}  # "the grid at 100 tasks, seed 0; one Objectworld map at 20 tasks, seeds 0 and 1; GoToLocal at 30 layouts, seed 1"
    assert "the grid at 100 tasks, seed 0; one Objectworld map at 20 tasks, seeds 0 and 1; GoToLocal at 30 layouts, seed 1" in rows["race"][5]
    evidence_no_worse = _route_table("results/which-learner/default")[0]
    assert (f"It is the cheapest route that keeps {evidence_no_worse} of the benchmark's 30 pairs (the race keeps "
            f"{no_worse}, at {statistics.median(ratios):.0f}x)") in _flat(GUIDE)
    assert f"against the race's median {statistics.median(ratios):.0f}x (its wall time)" in _flat(README)
    assert f"the race fits every candidate and costs a median {statistics.median(ratios):.0f}x (its wall time)" in _flat(GUIDE)
    assert {(p["preset"], p["n_tasks"], p["seed"]) for p in _route_pairs("results/which-learner/default") if not p["no_worse"]} == {
        ("sharing-objectworld-quick", 20, 0)}
    assert rows["evidence"][5] == "one Objectworld map at 20 tasks, seed 0 (flat kept)"


def test_the_guides_rank_agreement_figures_are_the_rank_diagnostics():
    """Why the evidence route: Spearman's rho of each route's scores (results/which-learner/diagnostics/rank's
    table), its rule's cost on two seeds, the confirmation by full fits (evidence-budget) and the
    removed leave-one-task-out route (diagnostics/routes/rank_approx_grid20_s2.json)."""
    table = _table((ROOT / "results/which-learner/diagnostics/rank/README.md").read_text(), "| point | seed | route | n |")
    by = {(r[1], r[2]): r for r in table}
    seeds = ("0", "1", "2")
    text = _flat(GUIDE)
    assert (f"Spearman's rho between its scores and the candidates' test deviations is {by['0', 'evidence'][4]}, "
            f"{by['1', 'evidence'][4]} and {by['2', 'evidence'][4]}, against {by['0', 'evidence'][5]}, {by['1', 'evidence'][5]} "
            f"and {by['2', 'evidence'][5]} for the exact") in text
    assert f"and {', '.join(by[s, 'race'][4] for s in seeds[:2])} and {by['2', 'race'][4]} for the race's" in text
    sizes = [int(r[3]) for r in table if r[2] in ("evidence", "pca", "race", "full")]
    assert f"one point, {min(sizes)}-{max(sizes)} candidates" in text
    (chosen,), (best,) = {by[s, "evidence"][7] for s in ("0", "2")}, {by[s, "evidence"][9] for s in ("0", "2")}
    assert (f"on two seeds ({chosen} instead of its best-scored {best}: {by['0', 'evidence'][8]} against "
            f"{by['0', 'evidence'][10]}, {by['2', 'evidence'][8]} against {by['2', 'evidence'][10]}") in text
    rank = _flat((ROOT / "results/which-learner/diagnostics/rank/README.md").read_text())
    flat, factorial = (dict(zip(seeds, map(float, x.split(", ")))) for x in
                       re.search(r"Flat: ([\d., ]+); factorial k = 5: ([\d., ]+)\.\)", rank).groups())
    assert all(float(by[s, "evidence"][8]) <= 1.1 * min(flat[s], factorial[s]) for s in ("0", "2"))
    assert "both within 10% of the better of flat and k = 5" in text
    confirm = _json("results/which-learner/diagnostics/evidence-budget/confirm_full_grid100_s1.json")
    scores = {(k, str(lam)): score for k, lam, score in confirm["confirm"]["rows"]}
    worse = 100 * (confirm["test_deviation"]["6,inf"] / confirm["test_deviation"]["5,inf"] - 1)
    assert f"the fitted (6, inf) transfers {worse:.1f}% worse than k = 5" in text
    assert f"Fully fitted, the two tie ({scores[5, 'inf']:.4f} and {scores[6, 'inf']:.4f})" in text
    budget = _flat((ROOT / "results/which-learner/diagnostics/evidence-budget/README.md").read_text())
    (errors,) = re.findall(r"rank \(6, inf\) above \(5, inf\) by ([\d.]+) standard errors", budget)
    assert f"PCA starts rank (6, inf) above (5, inf) by {errors} standard errors" in text
    record = _json("results/which-learner/diagnostics/routes/rank_approx_grid20_s2.json")
    approx, cpu = record["spearman"], record["cpu_s"]
    factorial = _json("results/which-learner/diagnostics/routes/routes_grid20_s2.json")["factorial"]["cpu_s"]
    route = cpu["fit_cpu_s"] + cpu["ij-damped_step_cpu_s"] + cpu["ij-damped_transfer_cpu_s"]
    assert f"at {route / factorial:.1f}x the factorial fit's CPU time (its fits, steps and held-out transfers)" in text
    assert (f"(Spearman {approx['ij-damped/test_deviation']:.2f} with their test deviations on the grid at 20 tasks, "
            f"against {approx['exact/test_deviation']:.2f} for exact 3-fold scores)") in text


def test_the_guides_paper_settings_costs_are_the_which_learner_readme():
    """The fixed fit's CPU with the paper's settings on the README grid and the confirmation's cost at
    100 tasks: the figures results/which-learner/default/README.md records for the runs they replaced."""
    record = _flat((ROOT / "results/which-learner/default/README.md").read_text())
    before = [float(x) for x in re.search(r"before, [\d.]+ s against ([\d.]+) s and [\d.]+ s against ([\d.]+) s\)", record).groups()]
    assert f"took 1.9-2.0 s of CPU against {min(before):.1f}-{max(before):.1f} s with the paper's settings" in _flat(GUIDE)
    runs = [_json(f"results/which-learner/default/auto-cost/{f}")["seeds"]["0"]["cpu_time_s"]["fixed"]
            for f in ("readme-evidence-race-pca.json", "readme-evidence.json")]
    assert f"took {min(runs):.1f}-{max(runs):.1f} s of CPU against" in _flat(GUIDE)
    now, then = re.search(r"the grid at 100 tasks ([\d.]+-[\d.]+x) in all \(([\d.]+-[\d.]+x) before it\)", record).groups()
    assert f"(the grid at 100 tasks: {now} in all instead of {then})" in _flat(GUIDE)


def test_the_readmes_sharing_verdicts_are_the_benchmarks_records():
    """The README's which-learner table, its "auto no worse (seeds)" column, and its prose: the choices
    and verdicts of the committed runs (route_table.py's pairs), and no transfer at max_iter."""
    pairs = _route_pairs("results/which-learner/default")
    assert len(pairs) == 30
    table = {r[0]: r[4] for r in _table(README, "| benchmark | flat | factorial (k = 5) | auto |")}
    for label, (preset, _, _, counts) in WHICH_LEARNER_ROWS.items():
        cells = table[label].split(" (beats both on ")[0].split(", ")
        for n, cell in zip(counts, cells, strict=True):
            points = [p for p in pairs if p["preset"] == preset and p["n_tasks"] == n]
            assert cell == f"{sum(p['no_worse'] for p in points)}/{len(points)}", (label, n, cell)
        if "beats both on" in table[label]:
            (n,) = counts
            beats = sum(p["score"]["adaptive"] < min(p["score"]["flat"], p["score"]["factorial"])
                        for p in pairs if p["preset"] == preset and p["n_tasks"] == n)
            assert table[label].endswith(f"(beats both on {beats})"), (label, beats)
    assert {p["chosen"] for p in pairs if not (p["preset"] == "sharing-grid" and p["n_tasks"] in (20, 100))} == {(1, 0.0)}
    assert "Outside the grid at 20 and 100 tasks auto keeps the flat model (k = 1, lambda = 0) on every seed" in _flat(README)
    logs = [line for f in ("maxiter-sharing-grid.log", "maxiter-other-presets.log")
            for line in (ROOT / "results/which-learner/default" / f).read_text().splitlines() if line.strip()]
    assert logs and not [line for line in logs if "transfer" in line.lower() or not line.startswith("GradIRL.fit")]
    assert "No transfer of the benchmark stops at `max_iter`." in _flat(README)


def test_the_guides_defaults_figures_are_the_defaults_study():
    """The guide's CPU of the defaults against the paper's algorithm: the grid's per-seed ratios of
    results/defaults/README.md ("The grid with the final defaults", §14) and the acceptance draws of
    per-task maps (as the README's figure)."""
    study = (ROOT / "results/defaults/README.md").read_text()
    grid = _table(study[study.index("**The grid with the final defaults, beside the paper's setting in the same process**"):],
                  "| objective | CPU ratio per seed")
    ratios = [float(x) for row in grid for x in row[1].split(", ")]
    maps = [r["cpu_s"] / e["cpu_s"] for r, e in _acceptance_draws()]
    assert (f"{min(ratios):.2f}-{max(ratios):.2f}x the CPU of the paper's algorithm on the paper's grid and "
            f"{min(maps):.2f}-{max(maps):.2f}x on per-task maps") in _flat(GUIDE)


def _magnitude(x):
    """How the guide writes a relative difference: one significant digit, ``3e-14``."""
    return f"{x:.0e}".replace("e-0", "e-")


def test_the_guides_planner_agreement_is_its_committed_measurement():
    """"What depends on the planner": results/planners/agreement.json, at the same rewards (the largest
    difference over the worlds of each discount) and along a fit."""
    run = _json("results/planners/agreement.json")
    same = run["same_rewards"]
    assert all(world["greedy_equal"] for world in same.values())
    worst = {(gamma, kind): max(v[kind] for w, v in same.items() if w.endswith(f"gamma {gamma}"))
             for gamma in ("0.9", "0.999") for kind in ("values", "losses, gradients and scores")}
    text = _flat(GUIDE)
    assert (f"`optimal_q` and `policy_evaluation` agree to {_magnitude(worst['0.9', 'values'])} relative at gamma = 0.9 and "
            f"{_magnitude(worst['0.999', 'values'])} at gamma = 0.999, the losses, their gradients and the scores to "
            f"{_magnitude(worst['0.9', 'losses, gradients and scores'])} at gamma = 0.9 and "
            f"{_magnitude(worst['0.999', 'losses, gradients and scores'])} at gamma = 0.999") in text
    fit = run["fit"]
    gradirl, factirl = fit["gradirl_deviation"], fit["factirl_deviation"]
    assert f"{gradirl[0]:.2f}" == f"{gradirl[1]:.2f}" and f"{factirl[0]:.2f}" != f"{factirl[1]:.2f}"
    assert (f"a 100-iteration `GradIRL` fit differs by {_magnitude(fit['gradirl_rewards'])} relative between planners "
            f"(its losses by {_magnitude(fit['gradirl_loss'])}, its mean deviation {gradirl[0]:.2f} with both), the paper's "
            f"`FactIRL` fit started from it by {_magnitude(fit['factirl_rewards'])} (its losses by "
            f"{_magnitude(fit['factirl_loss'])}, its mean deviation {factirl[0]:.2f} against {factirl[1]:.2f})") in text


def test_the_guides_planner_accuracy_is_its_committed_measurement():
    """"What depends on the planner": results/planners/accuracy.json, each planner against the exact
    (long-double) reference and the conditioning, on the 10x10 grid at gamma 0.999 and, for MCE's
    soft-value tolerance, over the worlds at gamma 0.9 and 0.99 without tied actions."""
    run = _json("results/planners/accuracy.json")
    grid = run["grid 10x10, gamma 0.999"]
    text = _flat(GUIDE)
    assert (f"the policy-matching gradient on that 10x10 grid at gamma = 0.999 is off by "
            f"{_magnitude(grid['dense']['its gradient'])} with the dense planner and "
            f"{_magnitude(grid['sparse-lu']['its gradient'])} with the sparse one, and the exact gradient itself moves by "
            f"{_magnitude(grid['conditioning']['its gradient'])} when every transition probability is perturbed") in text
    low = [v for name, v in run.items() if "feature" not in name and not name.endswith("gamma 0.999")]
    mce = ("mce", "mce gradient")
    error = max(v[p][k] for v in low for p in ("dense", "sparse-lu") for k in mce)
    conditioning = max(v["conditioning"][k] for v in low for k in mce)
    assert (f"at gamma = 0.9 and 0.99 it reaches {_magnitude(error)} relative in the MCE loss and gradient, where "
            f"the conditioning accounts for {_magnitude(conditioning)}") in text


def test_the_guides_figures_recorded_in_results_readmes_are_theirs():
    """Figures whose runs left only their README's statement (the run's records hold no such field):
    the guide quotes the README's figure. The 32x32 Objectworld's PCA shrink (results/objectworld) and
    GoToOpen's states per layout (results/babyai, also in ``reproduce --help``)."""
    from factirl_opt.lab.experiments.presets import PRESET_DESCRIPTIONS

    objectworld = _flat((ROOT / "results/objectworld/README.md").read_text())
    (shrink,) = re.findall(r"\(`pca_shrink`, (\d+)-fold here\)", objectworld)
    assert f"on 32x32 Objectworld the start shrinks {shrink}-fold" in _flat(GUIDE)
    babyai = (ROOT / "results/babyai/README.md").read_text()
    (states,) = re.findall(r"## `babyai-large` \(BabyAI-GoToOpen-v0, ~([\d,]+) states per layout\)", babyai)
    assert f"`babyai-large` on BabyAI-GoToOpen-v0 (about {states} states per layout)" in _flat(GUIDE)
    assert f"BabyAI-GoToOpen-v0 (about {states} states per layout)" in PRESET_DESCRIPTIONS["babyai-large"]


def test_the_guides_parameter_counts_are_the_estimators():
    import inspect

    from factirl_opt import FactIRL, GradIRL, MultiIntentIRL

    counts = {cls.__name__: len(inspect.signature(cls).parameters) for cls in (FactIRL, MultiIntentIRL, GradIRL)}
    assert (f"FactIRL takes {counts['FactIRL']} parameters, MultiIntentIRL {counts['MultiIntentIRL']} and GradIRL "
            f"{counts['GradIRL']}.") in _flat(GUIDE)


def test_the_readmes_two_factorial_figures_at_100_tasks_are_its_tables():
    """The README's note between its tables: the which-learner factorial cell and the headline's factorial
    test deviation at 100 tasks, from their summaries."""
    which = _mean(_summary("results/which-learner/default/sharing-grid/summary.csv"), "factorial", 100)
    headline = _mean(_summary("results/summary.csv"), "factorial", 100, 10)
    assert (f"The factorial column at 100 tasks ({which:.2f}) is the headline's learner ({headline:.2f})"
            in _flat(README))


def test_the_guides_model_estimates_are_its_examples_output():
    """"When the model is not given": the held-out scores the guide's own example prints (the ten lines'
    grid and demonstrations, the same exploration and held-out draws), computed as it computes them."""
    import numpy as np

    import factirl_opt as fo

    mdp = fo.GridWorld(size=10, p_success=0.7, gamma=0.9)
    R = fo.task_rewards(fo.random_dictionary(mdp.n_params, 5, rng=0), fo.random_coefficients(30, 5, rng=1),
                        mdp.n_states, mdp.n_actions)
    demos = fo.sample_demonstrations(mdp, R, n_demos=10, length=10, rng=2)
    logged = fo.mdp.as_transitions(demos)
    both = np.concatenate((logged, fo.mdp.sample_transitions(mdp, 20_000, rng=5)))
    heldout = fo.mdp.sample_transitions(mdp, 5_000, rng=6)

    def scores(model):
        logp = fo.mdp.transition_log_likelihood(model, heldout, reduction="none")
        return logp[np.isfinite(logp)].mean(), 1 - np.isfinite(logp).mean()

    _, ruled_out = scores(fo.estimate_mdp(logged, mdp.n_states, mdp.n_actions, mdp.gamma))
    _, uniform_ruled_out = scores(fo.estimate_mdp(logged, mdp.n_states, mdp.n_actions, mdp.gamma, prior="uniform"))
    gap = scores(mdp)[0] - scores(fo.estimate_mdp(both, mdp.n_states, mdp.n_actions, mdp.gamma))[0]
    assert uniform_ruled_out == 0  # "the uniform prior rules out none"
    assert (f"The demonstrations alone rule out {round(100 * ruled_out)}% of the held-out moves" in _flat(GUIDE)
            and f"bring the estimate within {gap:.2f} nats of the true model" in _flat(GUIDE))


def test_the_guides_posterior_cost_is_the_committed_measurement():
    """The posterior's cost the guide quotes: the range of `transfer_posterior_` over one default
    transfer in the committed runs on the README's "auto" model (one BLAS thread and the machine's)."""
    ratios = [run["posterior_over_saturation_transfer"]
              for f in ("results/transfer/posterior_cost.json", "results/transfer/posterior_cost_threads.json")
              for run in _json(f)["runs"]]
    low, high = _quoted(GUIDE, r"built when first read \(([\d.]+)-([\d.]+)x one transfer's CPU")
    assert _agrees(low, min(ratios)) and _agrees(high, max(ratios)), (low, high, ratios)


def test_the_guides_deviation_score_figures_are_its_diagnostic():
    """The guide's "Scoring by deviation": the rank agreements of the deviation score and of the held-out
    likelihood, and the evidence route's choices on the grid under each score, from
    results/which-learner/diagnostics/predicted/README.md (table.py's tables of its records)."""
    record = (ROOT / "results/which-learner/diagnostics/predicted/README.md").read_text()
    ranks = {(row[0], int(row[1])): (row[4], row[5]) for row in
             _table(record, "| point | seed | posterior | n | rho likelihood | rho deviation |") if row[2] == "conditional"}
    for point, text in (("objectworld-quick 20", "Spearman {dev} against {lik}"), ("grid 20", "({dev} against {lik}, seeds")):
        dev = ", ".join(ranks[point, s][1] for s in range(3))
        lik = ", ".join(ranks[point, s][0] for s in range(3))
        assert text.format(dev=dev, lik=lik) in _flat(GUIDE), (point, dev, lik)
    choices = {(row[2], int(row[1])): (row[4], row[5]) for row in
               _table(record, "| point | seed | score | route | chosen (k, lambda) |")
               if row[0] == "grid 20" and row[3] == "evidence"}
    flat = ", ".join(choices["deviation", s][1] for s in range(3))
    shared = ", ".join(choices["likelihood", s][0] for s in range(3))
    shared_dev = ", ".join(choices["likelihood", s][1] for s in range(3))
    assert f"keeps the flat model on every seed ({flat}, where the likelihood's evidence route takes {shared}: {shared_dev})" \
        in _flat(GUIDE)


def test_the_guides_importance_posterior_figures_are_the_ceiling_runs():
    """The guide's "Which new tasks will transfer worst": Spearman ranges of importance_posterior (10,000 draws),
    of transfer_posterior_ and of the exact posterior, and the cost, on 100 test tasks
    (results/transfer-prediction/bayes_ceiling_seed*_test100.json)."""
    runs = [_json(f"results/transfer-prediction/bayes_ceiling_seed{s}_test100.json") for s in (0, 1, 2, 1000)]
    default = [next(r for r in run["library_importance"] if r["n_particles"] == 10_000) for run in runs]

    def span(values):
        return f"{min(values):.2f}-{max(values):.2f}"

    text = _flat(GUIDE)
    assert f"at a Spearman coefficient of {span([r['spearman'] for r in default])} with its default 10,000 draws" in text
    assert f"against {span([run['library_conditional']['spearman'] for run in runs])} for `transfer_posterior_`" in text
    assert f"reaches {span([run['exact_posterior']['spearman'] for run in runs])}," in text
    cost = [r["cpu_in_transfers"] for r in default]
    assert f"{min(cost):.0f}-{max(cost):.0f} transfers of those 100 tasks" in text
    assert inspect.signature(fo.learners.importance_posterior).parameters["n_particles"].default == 10_000
