"""
Step solvers compared: loss against iterations
==============================================

FactIRL alternates an H-step (each task's coefficients) and a D-step (the shared dictionary);
each step is taken by a solver from the registry (``solvers.available_solvers()``). Here the
paper's Armijo gradient steps, L-BFGS and the matrix-free Gauss-Newton steps by conjugate
gradients (``gn-cg``) fit the same small problem; ``callback(iteration, loss)`` records the
total loss after each outer iteration. The performance page of this site compares them at the
paper's scale.
"""

import matplotlib.pyplot as plt

import factirl_opt as fo

mdp = fo.GridWorld(size=5)
D = fo.random_dictionary(mdp.n_params, 3, rng=0)
R = fo.task_rewards(D, fo.random_coefficients(12, 3, rng=1), mdp.n_states, mdp.n_actions)
demos = fo.sample_demonstrations(mdp, R, n_demos=8, length=8, rng=2)
flat = fo.GradIRL(max_iter=30).fit(mdp, demos)

fig, ax = plt.subplots(figsize=(6, 4))
for h_solver, d_solver in [("armijo", "armijo"), ("armijo", "lbfgs"), ("armijo", "gn-cg"), ("lbfgs", "lbfgs")]:
    losses = []
    model = fo.FactIRL(n_primitives=3, max_iter=15, solver=fo.SolverSettings(h_solver, d_solver=d_solver),
                       execution=fo.Execution(callback=lambda iteration, loss: losses.append(loss)))
    model.fit(mdp, demos, flat_rewards=flat.rewards_)
    dev = fo.deviation(mdp, R, model.rewards_).mean()
    ax.plot(range(1, len(losses) + 1), losses, marker=".", label=f"H {h_solver} | D {d_solver} (deviation {dev:.2f})")
ax.set_yscale("log")
ax.set_xlabel("outer iteration")
ax.set_ylabel("total loss (eq. 5 summed over tasks)")
ax.legend(fontsize=8)
fig.tight_layout()
plt.show()
