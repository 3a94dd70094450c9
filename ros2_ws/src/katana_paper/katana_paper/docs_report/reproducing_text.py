"""The fixed prose of docs/REPRODUCING.md, kept apart from the code that fills in the
figures so that either can be read and edited alone."""

from __future__ import annotations

from .formatting import table

REPRODUCING_INTRO = """\
# Reproducing the paper

How to reproduce the results of Ngo, Luciw, Förster and Schmidhuber (2013), what each figure
and claim means, and what this implementation measured, claim by claim. The figures come from
the committed result files (`docs/results/`, `docs/robot_truth.json`), each beside the command
and the CPU that made it; `python -m katana_paper.docs_report collect NAME` copies a fresh
result there and rewrites this page. At the end: the choices made where the paper leaves one
open, and the known deviations."""

SECTION_32_HOW = "\n".join([
    """\
The paper's abstract blocks world (section 3.1): 8 blocks, heights 0-7, a true stability model
per height (21 features), label noise from the true margin, stacks that topple.

```bash
make paper      # = katana-curiosity paper --jobs 2 --out runs/paper
```

It runs Q1, Q10, Conf and Random for 10 seeds of 10,000 steps each (alpha 1, theta 0.01,
gamma 0.95), on the compiled fast path, and writes into `runs/paper/`:
""",
    table(("file", "what"), [
        ("`summary.json`", "per strategy: final KL per height (mean and standard deviation over "
         "the seeds) and overall, direct and planned experience per height, highest state "
         "tried, planning calls"),
        ("`runs/<strategy>_seed<k>.csv`", "one row every 50 steps: KL per height and overall, "
         "cumulative direct and planned experience per height"),
        ("`fig4.png`", "cumulative direct and planned experience per height (Q1, mean of the "
         "seeds)"),
        ("`fig5.png`", "KL divergence per height over the steps (Q1)"),
        ("`fig6.png`, `fig7.png`", "the exploration focus at heights 1 and 2 at several steps: "
         "experience per feature, the unknown region, the learned model with its confidence "
         "band"),
        ("`fig8.png`", "the same for heights 1-6 at the end"),
        ("`fig9.png`", "KL per height over the steps for every strategy, and overall"),
    ]),
    """
`katana-curiosity paper --help` lists the options (seeds, experiments, strategies, alpha,
theta, gamma, jobs); `katana-curiosity explore` is one Q1 run with a progress bar.""",
])

SECTION_33_HOW = """\
The paper's robot experiment, on the PyBullet simulation of the Katana through the whole ROS 2
node graph: four blocks, heights 0-3, the paper's fovea features and its six actions. The
robot's true model is not given; it is measured.

```bash
katana-robot truth --trials 30 --out runs/robot-truth   # the truth (the longest: see below)
make robot-paper    # the runs against docs/robot_truth.json
katana-robot skill --goal-height 3 --trials 10 --model runs/robot-paper/runs/q1-s0
```

`make robot-paper` runs `katana-robot paper --seeds 4 --experiments 60 --strategies q1,random
--jobs 2 --truth docs/robot_truth.json --out runs/robot-paper`: each (strategy, seed) is one
`katana-demo` in its own process and ROS domain, two at a time. It writes `summary.json`,
`<strategy>-s<seed>.csv` (per experiment: mode, height, action, label, known beforehand, led
nowhere, KL per height), the run folders under `runs/`, and the figures `kl.png` (KL per
height over the experiments, mean and standard deviation of the seeds; cf. Figures 5 and 9),
`experience.png` (cf. Figure 4), `model.png` (the first q1 run's learned model with its
confidence band beside the truth; cf. Figure 13), `truth.png` and `contact_sheet.png` (twelve
consecutive experiments of the first run in the paper's four columns: fovea search, pick,
place, observation; cf. Figures 10-12). With `--reuse`, runs whose log already holds the
experiments are analysed again instead of being run."""

#: what the KL table of section 3.2's run shows, and the verdicts after it
PAPER_TABLE = ("Final KL divergence between the learned and the true models, mean of the seeds "
               "(lower is better; overall is the mean over the heights):")
PAPER_CLAIMS = "The paper's claims of section 3.2, checked against this run:"

#: what the table of section 3.3's runs shows, and the verdicts after it
ROBOT_TABLE = ("KL(measured truth || learned) per height at the end of the runs and overall (the "
               "mean over the measured heights), means of the seeds; an experiment is wasted "
               "when its pair was known, it came out as predicted and no experiment that "
               "taught the learner followed it before a reset:")
ROBOT_CLAIMS = "The paper's claims of section 3.3, against these runs:"
STUDY_ABOUT = """\
`make robot-paper` is too short to decide most of section 3.3's claims. `make robot-study`
runs them at the scale they need: every strategy, 20 seeds, 120 experiments, on Ray (each run a
task in its own ROS domain; `STUDY_ADDRESS` for a cluster whose machines share the folder), then
`katana-robot claims` on the result. It resumes and keeps complete runs, so it can run in
pieces; the part below is q1 and random over 24 seeds. Its learning curves, the mean KL over
the seeds with 95 % bootstrap bands per height and overall, are `kl.png` in the study's folder
(docs/figures/robot_study_kl.png)."""
STUDY_CLAIMS = "The paper's claims of section 3.3, against the study:"
AFTER30_ABOUT = """\
For each claim a run leaves INCONCLUSIVE, `katana-robot claims` says how many seeds would
decide it, from the spread of its seeds. The claims of the first 30 experiments need more seeds
than `make robot-paper` has, and runs of 30 experiments are cheap: the runs below are q1 and
random over 113 seeds of 30 experiments each (the claims of 60 and 120 experiments are not
evaluated on them). A count of seeds comes from the effect a run saw; where that effect is noise
around zero, it promises nothing, and the verdict below says so."""
AFTER30_CLAIMS = "The paper's claims of section 3.3, against these runs:"

TRUTH_ABOUT = """\
For every (height, action), `katana-robot truth` resets the sim, stacks blocks squarely
through the real `pick_and_place` action, asks `fovea/find_placement` for a location that
realises the pair, places a block there and reads the outcome from `sim/ground_truth`: the
block stayed if it lies flat on top of that stack and the stack has not moved. Only blocks
lying flat are picked. Pairs the fovea never realised are `null` in the file, listed under
`never_realised_by_the_fovea`, and count in no KL. `python -m katana_paper.docs_report collect
robot-truth` copies a new truth to `docs/robot_truth.json`, which `make robot-paper` reads."""

TRUTH_PARALLAX = """\
Where an action stays on the highest stack but falls on the lower ones ({actions} here), the
paper's own representation explains it: the fovea's bits test the hull of the *intersection*
of the stack's block pixels (section 2.2), and the top faces of a stack lie at different
heights, so the camera sees them shifted against each other. The intersection loses a few
millimetres on the side away from the camera's axis, and a location with few bits set has that
much more real overlap. Intersecting the footprints in the world would remove the parallax,
but would no longer be the paper's feature."""

SKILL_ABOUT = """\
`skill_node` (katana_curiosity) serves the `build_stack` action with the learned model only:
the MDP of section 2.4 on the learned transitions, a reward for reaching the target height, a
fall absorbing, no phantom rewards. Of the pairs the fovea offers it takes the one with the
highest planned value and plans again after every judged placement. The model knows heights,
not places, so of the instances that realise the chosen pair the skill takes the first whose
block, once placed, lies within the place reach of the height it makes
(`core.skill.choose_base`). The table is the last resort (a block put there takes one off a
stack). The paper's tricky situation (a two-stack whose top offers only poor placements, and
single blocks) arises on the sim at the edge of the reach, where a two-stack offers only
placements on its near edge: `test_paper_robot.py` builds it, and the node starts again
from height 1 and builds a stack of three. `katana-robot skill` runs `--trials` goals with the
learned model and with an untrained one (every margin 0), from the same scatters."""

BASELINES_ABOUT = "\n".join([
    """\
Strategies from the paper's related work, each a small class in
`katana_curiosity/core/strategies_baselines.py`, selectable like the paper's four:
""",
    table(("name", "strategy"), [
        ("`lp`", "learning progress (Oudeyer et al. 2007): a pair's phantom reward is the "
         "decrease of its prediction error, the older window of 5 minus the recent window of 5 "
         "(optimistic until a pair has 10 errors); plans every step"),
        ("`variance`", "the predictive variance of the label, 1 - margin^2, as phantom reward, "
         "no query condition (Hester and Stone 2012); plans every step"),
        ("`rmax`", "R-max-like counts: a pair is unknown until tried 5 times; Algorithm 1 with "
         "the count in place of the query condition"),
        ("`egreedy`", "the planned choice (phantom query reward), or with probability 0.1 a "
         "random instance"),
    ]),
    """
They run on the NumPy reference and plan every step, so they take minutes where the paper's
four take seconds.""",
])

FAITHFULNESS = """\
## Faithfulness: the choices the paper leaves open

### The abstract world and the algorithm

- **What i counts in h = log(1 + i).** i is the index of the predictor's next example: its own
  number of labelled examples plus one, counted per height. The lemma it simplifies sums over
  one classifier's examples, and the paper starts i at 1 (A_1 = I). So an untrained predictor
  has h = log 2 > 0 and finds everything unknown, where h = 0 would find nothing unknown.
- **The projection step.** Algorithm 2 writes max{0, (Delta - 1)/c} with sign(Delta). It is
  applied symmetrically, with |Delta|: a margin beyond +-1 on the instance is brought back to
  exactly +-1 before the RLS update (tested on hand-computed cases of both signs).
- **Which heights have predictors.** In the abstract world the table (height 0) has none: a
  placement there always succeeds. Heights 1-7 are learned, the 7 heights of Figure 9. On the
  robot heights 0-3 are all learned.
- **The true models.** The 21 margins of each u^s are drawn uniformly in [-1, 1] and sorted
  ascending. The bias component of u is 0, so |u.x| <= 1 for every feature and the label-flip
  probability (1 - |u.x|)/2 is always a probability (the paper's assumption 2).
- **Scan order of instances.** Every available height offers all 21 features, scanned in a
  uniformly random order that is new in every setting, as a fovea sweeping an image of randomly
  placed stacks would. The first unknown instance of such an order is uniformly distributed
  among the unknown instances, and `ShuffledSetting` samples it directly. Worlds with a real
  scan order (the robot's fovea) pass it explicitly, and the explorer takes the first unknown
  instance in that order.
- **Planned outcomes update the model.** Every executed placement is a labelled example of its
  height's predictor: the paper's agent "keeps on refining the learned model" while it exploits
  it (section 3.2, the action #16 / #20 story).
- **The MDP.** States are heights 0..8, and 8 is absorbing: no block is left to place. For a
  learned height s >= 1, P(s+1 | s, a) = (1 + Delta)/2 with Delta clipped to [-1, 1], and the
  rest is spread evenly over heights 1..s, as the toppling rule does. For a learned height 0
  the rest stays at 0. An unlearned height moves up with certainty.
- **Choosing (s\\*, a\\*).** The available state with the largest V(s) = max_a Q(s, a); ties go
  to the higher state, which builds towards the unknown. Then its best action.
- **LSPI.** LSTDQ-Model weighs every state-action pair once with its exact expected next
  features. Basis functions are pluggable (`Basis`, `TabularBasis`, `PolynomialBasis`). With
  the tabular default LSTDQ is exact policy evaluation, solved as the equivalent 9-state linear
  system; tests check that the two agree and that LSPI meets value iteration. Each plan starts
  from the last policy, and only the MDP rows of heights whose predictor changed are rebuilt.
- **Conf** plans at every step with R(s, a) = chi(s, a) for every learned pair and never
  queries directly: the paper's confidence intervals "are used themselves as rewards, instead
  of using a query condition".
- **Q10** is Q1 with the exploration policy re-solved on a fixed schedule (every 10
  observations, one per step) instead of on demand; planned choices in between use the last
  policy.
- **Random** takes a uniformly random instance of the setting, the table included.
- **Which block moves** (abstract world): a uniformly random top block that is not the top of
  the target stack; the abstract world has no geometry for the robot's "furthest block" rule.
- **Toppling.** A uniformly chosen level 1..s of the target stack keeps its block as the new
  top; everything above it, and the placed block, falls flat onto the table (height 1).
- **KL divergence.** KL(true || learned) between the Bernoulli outcome distributions
  P(stable) = (1 + margin)/2, averaged over the 21 features of a height. Learned margins are
  clipped to [-0.99, 0.99] first, so a margin outside [-1, 1] gives a large but finite value.
  "Overall" is the mean over heights 1-7.
- **Figure 4's vertical lines** mark the step after the last direct query of each height in
  the first seed's run.

### The robot

- **Fovea and features** (section 2.2). A 40x40 px window turned with the block below it; the
  convex hull of the block pixels inside it (for a stack, of the intersection of its blocks'
  pixels); five test points, the centre and (+-10, +-10) px; bits on + 1 = action 1..6; x = a
  one-hot action plus a bias (7 numbers); the state is the height under the fovea, 0 on the
  table. Occluded blocks' pixels come from the block memory's remembered top faces.
- **Scan order.** Fovea centres on a grid (6 px steps, within 36 px) around each stack top,
  heights ascending and nearest first, then free places on the table. Each distinct (state,
  action) is listed once per stack, at the first location that realises it.
  `fovea/find_placement` searches the same way, with a finer second pass, for a planned pair.
- **Available means executable.** An instance is offered only if the arm can reach the
  placement top-down (the reach, computed from the kinematics, shrinks with the stack's height:
  0.30, 0.28, 0.25 and 0.20 m from the pan axis for heights 0-3) and a pickable block outside
  the target stack exists. The paper's agent knows availability "from the known block
  positions".
- **Heights 0-3 are all learned**, with four blocks. A placement at height 0 is a placement on
  the table (action 1, no block in the fovea).
- **The label.** The robot parks out of view and waits for two fresh images (the first can
  predate the park). The judge says +1 if the placed block is visible on top within 15 mm of
  the placement point, upright, and the supporting stack has not moved by more than 6 mm, and
  -1 otherwise: a block that came to rest on its side on the stack fell over. `katana-demo`
  checks every verdict against the simulator's ground truth (for evaluation only; the learner
  never reads it) and reports the agreement in `summary.json`.
- **Which block moves.** The accessible top block furthest from the placement, never one of
  the target stack, as in the paper. Blocks the arm failed to reach are skipped until they
  move. A block that fell onto its side, or whose resting pose perception has not seen clearly
  since it last moved, is not picked: the paper stacks upright blocks only.
- **Failed grasps** are retried (`grasp_retries`, 2) with the block's refreshed pose; the paper
  resets and retries. An attempt that cannot be completed is dropped unlearned and counted by
  reason; after three drops in a row the world is reset (the sim scatters the blocks; on the
  hardware an operator is asked).
- **No experiment wasted** (section 4). Before a planned placement is made, the loop asks
  whether it leads towards an unknown pair: whether its pair is still unknown, or it is
  predicted to stay and grows a stack whose height has an unknown pair within the plan's reach.
  If not, the setting is changed instead (the world is reset), at most `setting_changes` (3)
  times in a row before the plan is followed anyway; when nothing is unknown anywhere every plan
  is made. The learner's feasibility table leaves out pairs a setting can never offer (action 5
  on a single block), so the planner does not chase them.
- **Resume.** The log is the record: on start the learner is rebuilt by replaying it (RLS is a
  deterministic function of its examples), and a line cut by a crash is dropped. The strategy's
  random stream is re-seeded with the number of replayed experiments.
- **Planned outcomes** update the model on the robot too."""

DEVIATIONS = """\
## Known deviations

- **Direct exploration does not end per height in the abstract world.** The paper's Figure 4
  shows direct exploration of a height terminating while planning takes over. Here a few
  features of each height have a true margin close to zero, and the confidence proxy
  chi = alpha sqrt(c log(1 + i)) falls below such a margin only after thousands of samples of
  that feature, so direct exploration of a height can go on, slowly, long after planning has
  begun (`fig4.png`). The paper does not give enough detail (its bias component of u, its
  exact i) to tell which choice makes its stages end earlier.
- **Action 5 (four bits) is never realised on a squarely built stack.** The fovea is turned
  with the block below, and on an axis-aligned square one corner point cannot leave the hull
  alone: a corner leaves together with its neighbour. It occurs on skewed stacks of two and
  more in the runs; on a single block it cannot occur at all, so the truth leaves it
  unmeasured and the learner's feasibility table leaves (1, 5) out of the plan. When (h, 5) is
  the only pair left unknown at a height, the loop places the block that makes that stack
  turned by 10 degrees against the one below, so that the stack offers it (DESIGN, "Turned
  for action 5").
- **The skewed two-stack of Figure 14 cannot be built on the sim.** Every two-stack that
  stands offers action 6 on top: the fovea's 20 px probe square fits in any overlap of two top
  faces wider than half a block, and a narrower overlap puts the upper block's centre beyond
  the edge below. The tricky situation is built instead at the edge of the reach (see the
  skill above).
- **The loop's placements differ from the truth's.** The truth places on stacks built squarely
  at one place with room around them; in the runs, single blocks lie anywhere in the reach, at
  any yaw and next to others. So a pair that always stays in the truth can fall now and then in
  the runs, and the learned model of that pair sits below the truth.
- **Contact-sheet gaps.** The camera runs at 10 Hz of sim time, so on the fast sim a short pick
  or place phase may have no frame; such a cell of `contact_sheet.png` is grey."""
