"""
How much to share: the number of primitives and the residual penalty, chosen by validation
==========================================================================================

``FactIRL(n_primitives="auto", residual_penalty="auto")`` chooses k and the residual penalty
lambda of ``R_i = Phi_i (D h_i + delta_i)`` by K-fold validation over tasks: build a dictionary on
some tasks, transfer it to each held-out task from one demonstration, and score the transferred
reward on that task's other demonstrations (their likelihood under the learner's policy
model, its temperature fitted per task). By default (``SharingSearch(route="evidence")``) k is
read off Minka's evidence of the flat rewards' principal components, and k/2, k and 2k, with
(lambda = 1) and without (lambda = inf) residuals, and the flat model (lambda = 0) are scored
from their PCA starts; a candidate that shares replaces the flat model only if its gain, paired
over the held-out tasks, is significant, and the fewest primitives within one standard error of
the best are taken. ``cv_results_`` holds the table (one entry per candidate in every array) and
``plot_validation`` draws it. Here 12 tasks on a 5x5 grid mix 3 primitive rewards.
"""

import matplotlib.pyplot as plt

import factirl_opt as fo
from factirl_opt.learners import plot_validation

mdp = fo.GridWorld(size=5, p_success=0.7, gamma=0.9)
D = fo.random_dictionary(mdp.n_params, 3, rng=0)
R = fo.task_rewards(D, fo.random_coefficients(12, 3, rng=1), mdp.n_states, mdp.n_actions)
demos = fo.sample_demonstrations(mdp, R, n_demos=6, length=10, rng=2)

model = fo.FactIRL(n_primitives="auto", residual_penalty="auto", max_iter=10, rng=0).fit(mdp, demos)
print(f"chosen: k = {model.n_primitives_}, lambda = {model.residual_penalty_}")
table = model.cv_results_
for k, lam, score, chosen in zip(table["param_n_primitives"], table["param_residual_penalty"],
                                 table["mean_test_score"], table["chosen"]):
    print(f"k = {k}, lambda = {lam}: held-out score {score:.3f}{'  (chosen)' if chosen else ''}")

fig, ax = plt.subplots(figsize=(7, 4))
plot_validation(model, ax=ax)
ax.set_title("validation over tasks (circled: the chosen pair)")
fig.tight_layout()
plt.show()
