"""The planner's configuration (the scenario's ``planner:`` section) and its
validation. Units: metres, seconds, degrees where a name says ``_deg``.

(No ``from __future__ import annotations`` here: Drake's ``yaml_load_typed``
reads the fields' types.)"""

import dataclasses as dc

from lmap_drake.config_checks import CheckRules
from lmap_drake.errors import ConfigError


@dc.dataclass
class PlannerConfig:
    """LMAP candidates, checks, visibility and selection (Sec. III-C).

    ``max_energy_per_node`` (m^2; 0 disables): actions whose predicted
    ARAP energy per deformable leaf node exceeds it are rejected as a damage
    risk (the paper's score, normalised over all checked actions, then picks
    among the rest). A deviation from the paper, whose min-max normalised
    score gives energy no absolute meaning (when every candidate is risky it
    still picks one). Per node, because the energy is a sum over the graph
    and grows with leaf size at equal strain. The default is calibrated on
    simulated episodes by ``scripts/calibrate_energy_cap.py``.

    ``force_action`` ([grasp_id, direction_id, distance m]; empty = off):
    execute this candidate of the LMAP table instead of the best-scoring one
    (what-if runs and ``scripts/action_oracle.py``). It must pass the IK and
    robot collision checks; the energy cap, leaf-fruit and early-stop
    verdicts are kept in its ``reason`` but do not stop it.

    ``speed_scale`` (0, 1] scales every arm motion of the episode (joint
    moves, approach, pull, release, retreat); on hardware the joint speed is
    also bounded by ``hardware.ur.joint_speed_limit``. ``release_and_retreat``
    ends the episode by opening the gripper and backing out to the start
    pose (false: the episode ends holding the leaf after the re-estimation).
    ``approach_speed`` (m/s): the TCP's mean speed on the final approach
    (pre-grasp -> grasp, open gripper) and on the way back out after the
    release; near a wrist singularity the joints (at most half their
    velocity limit) set a slower pace. Until 2026-11-26 the approach was timed
    by the joints alone at 0.15 of their limit: 5 cm took 0.42-0.74 s on
    the single-fruit suite's grasps (7-12 cm/s) but 4.4 s (1.1 cm/s) where
    the wrist turned 1.3 rad along it (``three_fruits_default``); 0.1 keeps
    the typical pace and ends the slow ones (0.05 made every single-fruit
    episode about 1 simulated second longer).
    ``return_speed_scale``: the held leaf is carried back to where it was
    grasped (before the release) this many times faster than it was moved
    (the pull's pace: 3 cm/s, turns at 0.5 rad/s).

    ``max_pull_force`` (N; 0 = off): the force guard. While the held leaf
    is moved (the action and its continuations), the station's wrist force
    (``ur5.wrist_force``) is compared with its value at the pre-grasp pose
    (before the open gripper reaches into the plant, so a grasp that
    already presses the leaf or a neighbour counts); when it has risen more
    than this, the motion stops where it
    is, the view is taken, no further motion is planned, and the leaf is
    carried back along what was executed and released (the target's record
    says so). In the FEM world the rise reads 0.75-1.0 of the grasped
    leaf's petiole load and follows it within one sample
    (docs/explanation/planner-parameters.md, "The force guard"). 8 N: the
    lowest load at which a held blade was measured to tear (a 30 deg twist,
    strain 1.101 at a 12.0 N petiole load, far below the 15 N hazard
    limit) times the rise's lowest ratio to the load (0.75) is 9 N; 8 N
    leaves a newton for the stop's lag (the fastest overload measured rose
    about 27 N/s: 0.5 N per 0.02 s control step). ``max_retreat_force`` (N;
    0 = off) guards the way back out of the plant after the release (grasp
    -> pre-grasp, the open gripper backing out), measured from the wrist
    force as the retreat begins: nothing is held there, so a rise means a
    leaf caught on the gripper (one sprung back around its body while the
    leaf was held); the arm then goes back to where it released the leaf
    (which unloads the caught one) and the episode aborts. That way out
    always moves at the pull's pace: at the approach's 10 cm/s the tool's
    own inertia read 3 N as it started, and a caught leaf loaded its
    petiole about 50 N/s. At 3 cm/s the clean ways out read at most 0.3 N
    in simulation, so 3 N works there. The default is 8 N, the pull's
    limit: at 3 N it stopped every episode on the hardware path (the
    digital twin, whose gripper reported itself open before its fingers
    let the leaf go, so the arm backed out still holding it); at 8 N the
    twin's episodes finish, and the way out that dragged a caught leaf in
    ``gh_random_8585_001`` (segnet) to 860 N at its petiole with the guard
    off stopped early: that leaf's worst load stayed the 17.5 N it took
    at the grasp.
    A station without the port (a replay) has no guard.

    ``release_opening`` (m; 0 = the approach's opening): how far past the
    opening measured on the leaf the pads open to let it go, once it is
    carried back to where it was grasped; never wider than the approach's
    opening. The way out waits (at most 2 s) until the gripper reports that
    opening (``systems.arm_status.PadsOpened``). 1 cm: each pad moves
    5 mm, less than the FEM brush study's largest push measured harmless
    (0.8 cm). Opening to the approach's
    3.5 cm moved each pad 1.7 cm into a leaf that had come to lie beside
    it while the held one was away: in ``gh_fruit_behind_stem`` (label
    oracle, the arm 45 cm in front of the row) a hidden occluder was
    pressed at 5.7 N to a blade strain of 1.23 during the release; at 1 cm
    that episode is safe with the same reveal
    (docs/explanation/planner-parameters.md, "The release opens the pads
    only as far as it must").

    ``hidden_leaf_reach`` (m; 0 = off): a grasp is refused when another
    leaf's points lie behind the grasped blade (as the camera sees it), at a
    depth the closing pads pass through, within this distance of the pads'
    footprint: that leaf goes on under the held blade, out of sight, and
    may be pinched (``approach.LeafBetweenPads``). 2 cm, half the width of
    a typical blade (4 cm; the greenhouse generator's blades are 2.5-10 cm
    wide): a leaf that ducks under the held one beside the pads reaches
    them unless it is narrower than that. In ``gh_green_two_leaves_and_red``
    (label oracle, the arm 45 cm in front of the row) the pads of a fourth
    motion closed on true leaf 2 with hidden leaf 0 lying 1 cm behind it
    (474 pixels seen, the nearest 3 cm from the grasp): blade strain 1.15
    and 1.18 in two runs (docs/explanation/dense-canopy.md, "A leaf hidden
    under the held one").

    ``action_families``: 'pull' (the paper's straight pulls: ``distances``
    along the ``num_directions`` fixed directions) and 'arc' (ours: the
    grasped leaf swung about its estimated petiole attachment by each of
    ``arc_angles_deg`` about ``num_arc_axes`` axes perpendicular to the
    attachment-grasp line, the gripper turning with it; direction ids
    100 + axis) and 'twist' (ours: the gripper turns by each of
    ``twist_angles_deg``, both senses, about the attachment-grasp line, so
    the blade turns toward edge-on about it; direction ids 200, 201).
    ``force_action`` names an arc by its chord (m).
    ``continuation_families``: the families a re-plan from the held leaf
    may use (those also in ``action_families``). Pulls are left out by
    default: a straight pull from a leaf already turned is what overloaded
    the petiole among the planner's continuations (2 cm pulls after an
    arc, 2 of 12 past 15 N on random suites: 15.3 and 17.4 N), while the
    arcs and twists it chose there stayed below 13 N.
    ``continue_after_pull``: whether a straight pull may be followed by a
    further motion. Off by default: a pull loads the petiole along its
    axis and a turn after it compounds that load. In the multi-fruit
    plants, where the first motion is a pull more often, 3 of 4 reveals
    that turned the leaf after a pull reached 13.0-17.6 N on the petiole
    (a fifth ended its episode at 15.4 N), 9 single-motion reveals at most
    10.7 N; in the single-plant suites the first motion was a pull in none
    of 113 episodes.

    ``targets``: ``largest`` reveals the most-seen fruit (the paper's
    single-fruit episode); ``all`` reveals every fruit of the plant in turn
    (paper Sec. III-F): each fruit completed on its own, the least visible
    first, the leaf that hides it chosen among its occluding leaves by
    predicted visibility then energy; each target is planned, grasped,
    moved, observed, re-estimated, released and retreated from before the
    next (``planning.targets``, ``systems.planning.PlantPlanning``).

    ``ready_distances`` (m): the approach comes in along the gripper's axis
    from a ready pose this far behind the pre-grasp (itself
    ``pregrasp_distance`` behind the grasp); when the arm cannot reach a
    ready pose or would hit something on the way to the pre-grasp, the
    next distance is tried (the grasp and the last 5 cm of the approach
    stay the same; the action's record says which was used,
    ``ready_distance``). On the far side of a plant the 8 cm ready pose can
    lie beyond the UR5's reach: with the 2 cm fallback two fruits of the
    multi-fruit suite were revealed further (0.31 -> 0.79 and 0.67 -> 0.76);
    the single-fruit suite chose the same actions either way. [0.08] keeps
    the one distance.

    ``min_usable_grasps``: when fewer grasps than this pass the IK and robot
    checks (a small leaf near the branch, an edge the arm reaches
    awkwardly), the failed grasps are retried with the gripper turned 180
    deg about its approach axis and with the approach tilted +-35 and +-70
    deg in the blade's plane (70: nearly from the leaf's side), and grasps
    between half of ``min_branch_distance`` and it are tried too
    (``planning.candidates.GraspAlternatives``; the record's ``approach_tilt_deg``
    and ``gripper_turned`` say which was used; 0 = never). Still short,
    the grasp set is made again at each of ``deeper_grasp_insets`` (m
    inside the leaf's outline, in turn, until enough pass; grasp ids 100 +
    i, 200 + i; [] = never): on the crowded multi-fruit plants every grasp
    1 cm inside the rim could fail a robot check by a few millimetres.

    ``max_replans``: after the action and the re-estimation, while the
    fruit is predicted less than ``early_stop_fraction`` visible, plan a
    further motion from the held leaf (its deformation predicted from the
    leaf as now observed) up to this many times; each is executed, held and
    observed like the first. The leaf is carried back along all of them
    before it is released. A further motion must raise the predicted
    visibility by at least ``min_replan_gain`` (fraction of the fruit's
    voxels) over the leaf held where it is.

    ``min_visibility_gain``: the first motion too must raise the fruit's
    predicted visibility by at least this fraction of its surface voxels
    over the leaf left where it is; an action below it is rejected with the
    reason, and a plan whose every action is below it is
    'no_feasible_action', never 'ok' (a leaf grasped for nothing is risk
    for nothing). The same bar as ``min_replan_gain``: a gain smaller than
    this is within what one voxel layer of the fruit's rim and the
    deformation prediction's error shift.

    ``hinge_bending_weight`` (m^2 per rad^2 per leaf node): the petiole's
    bending at its attachment, added to every action's predicted energy as
    weight * theta^2, theta the turn of the grasp point about the estimated
    attachment (``planning.energy.PetioleBendingEnergy``; 0 = the ARAP energy
    alone, as in the paper). Chosen on two suite scenes with
    ``scripts/eval_hazard_prediction.py`` (it maximises the Spearman rank
    correlation of the predicted energy with the FEM petiole force over
    pulls and arcs together) and checked on two others.

    ``max_hinge_deg``: no action (with the motions before it) may turn the
    grasp more than this about the attachment. In the FEM world 45-degree
    arcs loaded the petiole up to 11 N on four suite scenes, while on random
    scenes 60-degree turns reached 15.1-15.3 N (the plant-hazard limit is
    15 N), so the arcs stop at 45 degrees and re-planning may add a little
    (see ``max_replan_turn_deg``).

    ``max_replan_turn_deg``: a re-plan from the held leaf may not bring the
    equivalent turn (from the first grasp) past this: 45, the largest arc.
    At ``max_hinge_deg`` (50) a re-plan could add a 30-degree twist to a
    45-degree arc (equivalent turn 47.4); on a random multi-fruit plant
    that loaded the petiole 16.2 N. Executed from the planner's own grasps
    on three such plants (``scripts/eval_hazard_prediction.py --then_twist
    30 --then_arc 15 30 --then_turn_band 45 50``), of the continuations
    into 45-50 degrees after 45-degree arcs that passed the leaf checks and
    stayed under 15 N, twists took the load past 15 N 12 times in 58 and
    arcs 4 times in 40 (the hinge estimate is 0.6-2 cm off there; the
    petiole's true turn after the arc was 36-80 degrees). On the
    single-fruit suite four such 15-degree arcs had stayed at 7.6-9.2 N and
    added 0.04-0.09 visibility.

    ``petiole_torsion_ratio``: a twist loads the petiole in torsion; the
    turn that the bending term and ``max_hinge_deg`` see is the equivalent
    sqrt(bend^2 + ratio twist^2) (``planning.energy.EquivalentTurnDeg``), the
    ratio being the petiole's torsional to bending stiffness. 0.25 is the
    geometric mean of the bounds the FEM world gave on two random suites
    (seeds 157 and 211): 45-degree arcs followed by 30-degree twists loaded
    the petiole 7.3-11.7 N (12 episodes: allowed needs ratio <= 0.53), by
    60-degree twists 11.5-15.6 N (3: rejected needs ratio > 0.13).

    ``max_tether_elongation`` (m): no action (with the motions before it)
    may end the grasp farther than this beyond its starting distance from
    the estimated attachment (0 = no limit). The petiole is stiff along its
    axis: of 160 straight pulls executed in four suite scenes
    (``scripts/eval_hazard_prediction.py``), those lengthening that
    distance by more than 2 cm loaded the petiole past 15 N 33 times in 37,
    by 1.5-2 cm 4 in 12, by at most 1.5 cm 15 in 111 (arcs and twists keep
    it); two straight 8 cm lifts on multi-fruit plants loaded it 19.7 and
    23.6 N.

    ``max_pull_distance`` (m): the longest straight pull from a grasp 10 cm
    from the estimated attachment, scaled by (L / 10 cm)^2 for a grasp L
    from it (``planning.energy.MaxPullDistance``; 0 = no cap; arcs are capped
    by ``arc_lever_reference``, twists by ``max_hinge_misfit``). Like
    ``max_energy_per_node`` it vetoes after the scores are normalised over
    every action that passed the checks, so it does not re-rank the rest
    (removing the longer pulls first turned the single-fruit suite's 45°
    arcs into 30° ones: visibility 0.99 -> 0.95). The leaf acts as a beam
    clamped at its petiole: moving the grasp by d bends the petiole by a
    moment that grows as d / L^2. Measured on five random multi-fruit
    plants from the planner's own grasps (``scripts/eval_hazard_prediction.py``
    on ``make_suite.py --multi --random`` seeds 5151 and 5252; 380 pulls of
    1.5-4.5 cm): at a lever of 6.2-7 cm a 1.5 cm pull loaded the petiole
    13.8-14.8 N, at 10-12 cm 4-5 N. Of the 296 pulls that passed the energy,
    hinge and tether limits, 13 went past 15 N (up to 30.2 N); with this
    cap none of the 166 left did, the largest 11.9 N (3.5 cm: 14.9 N, where
    the attachment estimate was 3 cm off). On the single-fruit suite's four
    hazard scenes the same cap keeps 97 of 144 such pulls, the largest
    9.6 N. The scaling is not extrapolated past the longest pull
    measured: the cap is at most 4.5 cm (``energy.MEASURED_PULL_MAX``; two
    6 cm pulls it allowed at a 14 cm lever loaded their petioles 19.4 and
    21.1 N).

    ``arc_lever_reference`` (m): an arc about the estimated attachment may
    turn at most 45 deg x L / this, L the grasp's distance to the
    attachment (``planning.energy.MaxArcAngle``; 0 = no cap): turning the
    blade takes a moment at the petiole, and the grasp supplies it with a
    force that grows as the lever shortens. A veto after scoring, like the
    pull cap. Over 155 arcs that evaluations chose first (suites, random
    plants, pepper meshes not of the family), the 45 deg arcs from grasps
    under 7 cm from the attachment loaded the petiole past 15 N in 2 of 18
    (16.4 and 15.8 N), none of the 8 such 30 deg arcs did (at most 12.1 N),
    and 45 deg arcs from 9 cm or more stayed under 12.2 N. At 7.5 cm a 45
    deg arc needs L >= 7.5 cm, a 30 deg one 5 cm.

    ``hinge_error`` (m) and ``max_hinge_misfit``: the held blade's misfit
    to a wrong hinge estimate. The pads hold the blade rigidly; an arc or
    a twist about the estimated attachment moves the true one, ``hinge_error``
    off, by up to 2 sin(turn / 2) x hinge_error in the gripper's frame, and
    the blade and petiole between the pads and the attachment (the lever L)
    must take it up (``planning.hazard.HingeMisfitStrain``; the turn counted
    from the first grasp when re-planning). An action whose
    2 sin(turn / 2) hinge_error / L is above ``max_hinge_misfit`` is vetoed
    after scoring, like the lever caps (0 = off). It bounds twists, which
    the lever caps leave alone: two 60 deg twists from 3.9 and 4.6 cm
    (misfit 0.77 and 0.66) tore the held blade (95th-percentile stretch 1.12
    and 1.10; the tear limit is 1.10) in the greenhouse suite. 3 cm is the
    largest hinge error the hazard studies measured (0.6-3.2 cm); 0.4 lies
    below the smallest misfit that tore a blade in the FEM study
    (``scripts/eval_hazard_prediction.py``, 0.42) and is no tighter than the
    arc cap for first arcs (at most 0.31 there). ``hinge_error`` is the
    least error assumed: a leaf seen farther from its branch than that has
    an unseen petiole at least that long, and the estimate can be off by
    about as much (``attachment.UnseenPetiole``; 4.1 and 4.3 cm off for
    leaves seen 4.4 cm from the branch): its turns are bounded at that
    distance instead.

    ``robot_fruit_margin`` (m): every part of the robot but the two fingers
    (arm, wrist, the gripper's body and coupling) keeps this far from every
    estimated fruit; the fingers, which must reach a leaf lying on its
    fruit, keep ``collision_margin``. A fruit's estimate is seen on one
    side only, and its unseen side can be a centimetre off: in
    ``four_fruits`` the gripper's coupling ended an arc 5.8 mm from the
    estimate of a fully visible fruit and 5.1 mm inside the real one (237
    N on the fruit). Off (below ``collision_margin``) means the one margin.

    ``max_brush_displacement`` (m; 0 = any contact refused): the robot may
    brush leaves it does not hold, on the approach (the joint move to the
    via pose, the ready pose, the pre-grasp and the final approach) and at
    the action's checked poses, when it pushes each of their observed
    points at most this far (how far the point's leaf must move along its
    normal to clear the robot's geometry by ``collision_margin``, per
    checked pose); the grasped leaf
    (outside the pads, on the approach) and other leaves' points within
    3 cm of a fruit keep the margin, and nearer the branch the push
    allowed shrinks so that the predicted petiole load stays at most 5 N,
    a third of the 15 N plant-hazard limit (``planning.robot_checks.
    LeafContact``, ``BrushAllowance``: the load k d / L^2 of a push d at a
    lever L, k measured on the FEM leaf; 1 cm from 10.2 cm from the branch
    on). 1 cm, not more: the FEM study's pushes of at most 0.8 cm loaded
    the petiole at most 0.5 N, while one of 1.2 cm (within the load bound)
    strained the blade past the tear limit, pressed by a pad's edge.
    docs/explanation/dense-canopy.md quotes the data and the measurements.

    ``push_back_check``: a straight pull that moves the grasp away from the
    camera (by s, its component along the camera-grasp ray) is also checked
    with the observed leaf shifted back by s along that ray, whole: the
    leaf-fruit check then applies to it as to the predicted leaf. A blade
    pushed back at one point can slide back on its petiole instead of
    bending as the graph predicts, and behind a leaf that hides a fruit
    lies that fruit. In ``gh_random_5353_001`` (label oracle, the fruit's
    estimate 0.13 cm Chamfer off) a 4 cm pull up, left and back (2.0 cm
    back) was predicted to lift the blade's base over the fruit (+2.2 cm
    up, clear by 17.8 mm); the FEM blade's base went 2.3 cm back and 0.5
    cm up, onto the fruit (2.8 N). A stiffer virtual petiole in the graph
    predicted it staying put (wrong too). Arcs and twists are turns about
    the hinge and are not shifted. docs/explanation/dense-canopy.md
    ("A leaf pushed back") has the measurements and what it costs.

    ``check_leaf_branch``: reject an action whose predicted leaf ends within
    ``collision_margin`` of the completed branch (stems and shoots) after
    moving toward it, as the paper's leaf-fruit check does for the fruit
    (leaf points resting that close, the petiole's base, are not counted).
    The deformation graph does not collide the leaf with the branch, while
    the FEM leaf is pressed against it and loads its own petiole. Off by
    default: on two random multi-fruit plants (seed 5151, 45 arcs and
    twists of 45-60 deg from the planner's grasps,
    ``scripts/eval_hazard_prediction.py``, column ``leaf_branch``) it
    caught none of the three motions that pressed the held leaf into the
    main stem (17-28 N) and rejected two harmless ones (4-9 N): the
    prediction and the completed stem are not yet accurate enough for it.

    ``max_reveals_per_fruit`` (``targets: all``): how many times one fruit
    may be revealed (2, the default; 1 is the paper's one leaf per fruit).
    A further reveal costs a grasp cycle; on the multi-fruit suite 2 gave
    16 / 18 fruits >= 0.9 over the fused views against 12 / 18 with 1, the
    same safety, and 3-fruit episodes of 70-76 s (two workers); see the
    README. A fruit under two leaves shows at most what
    one leaf alone hides while that leaf is moved; the other leaf's part is
    seen only when it is moved in turn (the views are fused, so the shape
    re-estimate sees both parts). A fruit is revealed again after every
    fruit's first reveal, and only if a leaf not moved yet alone hides at
    least ``next_leaf_min_gain`` (fraction of its surface) in the current
    view, the bar ``min_replan_gain`` sets for a further motion; that part
    was hidden in every earlier view too, since that leaf never moved. The
    leaf moved before is found in the current view by its points in the
    view its move was planned in (``planning.targets.SeparateMovedLeaves``;
    where the segmenter joined it to a touching blade, it is split off).
    ``reveal_moved_leaf_again``: when no leaf not moved yet hides that
    much, a leaf moved before may be moved again if it alone hides at
    least ``next_leaf_min_gain`` of the fruit's surface that no view has
    shown (marked by pixel, ``VisibilityModel.Observed``, from the fruit's
    points in the current view and in its re-estimates made while a leaf
    was held, ``systems.planning._ShownFruitPoints``); its actions then
    score by that surface (N_vis), and the reveal is made only if its
    chosen action shows at least ``next_leaf_min_gain`` of it.

    ``fruit_shapes``: what the robot-fruit checks (approach, action poses,
    executed path) and the leaf-fruit check (the predicted leaf) keep
    clear of: ``union`` = every shape the view leaves plausible (each
    fruit's estimate and its kept shape hypotheses,
    ``shape.ssc.num_hypotheses``; ``planning.collision.FruitSetSdf``),
    ``estimate`` = the estimates alone (the paper's check, and the only one
    before the hypotheses). ``visibility_shapes``: ``expected`` scores an
    action's visibility as the mean over the target's kept shapes of the
    fraction seen (``planning.visibility``), ``estimate`` on the estimate
    alone. Without hypotheses both are the estimate. See
    docs/explanation/planner-parameters.md."""
    num_grasps: int = 15  # grasp points evenly spaced along the leaf's outline (convex hull)
    grasp_inset: float = 0.01  # m: grasp points lie this far inside the leaf's outline
    # the first this many of the paper's 14 pull directions (W: 6 axial, then 8 diagonal)
    num_directions: int = 14
    # deg: pulls are kept only within this angle of the line from the grasp to the
    # nearest branch point (the leaf is not pulled away from its branch)
    max_branch_angle_deg: float = 120.0
    # m, the straight pulls' lengths (the random and upward baselines pull the longest)
    distances: list[float] = dc.field(default_factory=lambda: [0.02, 0.04, 0.06, 0.08])
    # fraction of the fruit predicted visible that is enough: longer moves of that
    # grasp and direction, re-plans and further reveals are not needed beyond it
    early_stop_fraction: float = 0.95
    pregrasp_distance: float = 0.05  # m: the pre-grasp sits this far back from the grasp (TCP z)
    pregrasp_opening: float = 0.035  # m, pad opening on the approach (narrower if the pads hit)
    release_opening: float = 0.01    # m the pads open past the leaf to let go (0: the approach's)
    # m: another leaf seen behind the held blade this near the pads may pass between them (0: off)
    hidden_leaf_reach: float = 0.02
    ready_distances: list[float] = dc.field(default_factory=lambda: [0.08, 0.02])
    grasp_close_width: float = 0.0     # the closing ramp's end: fully closed, so the pads meet a real 0.2-0.5 mm leaf
    gripper_close_speed: float = 0.05  # m/s: the commanded opening closes on the leaf this fast
    # m: in simulation (and the twin) the leaf is attached to the pads once their
    # opening, closing, is at most this
    grasp_attach_opening: float = 0.006
    min_branch_distance: float = 0.06  # m: grasps closer than this to a branch point are dropped
    min_usable_grasps: int = 3
    deeper_grasp_insets: list[float] = dc.field(default_factory=lambda: [0.02, 0.03])
    targets: str = "largest"   # largest | all
    visibility_voxel: float = 0.003  # m, voxel of the fruit-visibility prediction (N_vis)
    # m: clearance the robot keeps from the fruits, branch and leaves, and the
    # predicted leaf from the fruit
    collision_margin: float = 0.005
    robot_fruit_margin: float = 0.015
    max_brush_displacement: float = 0.01  # m: push allowed on leaves not held (0 = none)
    energy_weight: float = 1.0  # lambda of the score N_vis - lambda E (both min-max normalised)
    max_energy_per_node: float = 5.9e-7
    force_action: list[float] = dc.field(default_factory=list)
    method: str = "lmap"  # lmap | random | upward | min_overlap
    speed_scale: float = 1.0
    approach_speed: float = 0.1
    return_speed_scale: float = 1.0
    max_pull_force: float = 8.0    # N: the force guard on a held leaf's motion (0 = off)
    max_retreat_force: float = 8.0  # N: the force guard backing out of the plant (0 = off)
    release_and_retreat: bool = True
    action_families: list[str] = dc.field(default_factory=lambda: ["pull", "arc", "twist"])
    continuation_families: list[str] = dc.field(default_factory=lambda: ["arc", "twist"])
    continue_after_pull: bool = False
    # deg, the arcs' turns about the estimated petiole attachment
    arc_angles_deg: list[float] = dc.field(default_factory=lambda: [15.0, 30.0, 45.0])
    # deg, the twists' turns about the attachment-grasp line (both senses)
    twist_angles_deg: list[float] = dc.field(default_factory=lambda: [30.0, 60.0])
    num_arc_axes: int = 8  # arc axes, evenly spread, perpendicular to the attachment-grasp line
    max_replans: int = 1
    min_replan_gain: float = 0.05
    min_visibility_gain: float = 0.05
    # [0, 1]: a fruit instance whose segmentation confidence (perception's
    # SemanticScene.fruit_confidence) is below this is no target (it stays an
    # obstacle and occluder; plan.json skipped_fruits says so); 0 = every
    # instance is a target. 0.75: fruit at least three times as likely as the
    # other classes together; why, measured: docs/explanation/dense-canopy.md.
    min_fruit_confidence: float = 0.75
    hinge_bending_weight: float = 3.0e-7
    max_hinge_deg: float = 50.0
    max_replan_turn_deg: float = 45.0  # deg: cap on the equivalent turn after a re-plan
    petiole_torsion_ratio: float = 0.25
    max_tether_elongation: float = 0.015
    max_pull_distance: float = 0.03
    arc_lever_reference: float = 0.075
    # m: how far the hinge estimate may be from the true petiole attachment
    # (at least; a leaf seen farther from its branch: that distance)
    hinge_error: float = 0.03
    # 2 sin(turn / 2) hinge_error / lever above this: the held blade may tear (0 = off)
    max_hinge_misfit: float = 0.4
    check_leaf_branch: bool = False
    push_back_check: bool = True
    max_reveals_per_fruit: int = 2
    next_leaf_min_gain: float = 0.05
    reveal_moved_leaf_again: bool = True
    # union | estimate: the fruit shapes the robot-fruit and leaf-fruit checks keep
    # clear of (union: each fruit's estimate and its kept shape hypotheses; the
    # default since its run-vs-bag difference was traced to the bag's withheld
    # free space, docs/explanation/planner-parameters.md)
    fruit_shapes: str = "union"
    # expected | estimate: visibility scored as the mean over the target's kept
    # shape hypotheses (expected) or on its estimate alone
    visibility_shapes: str = "expected"


# m: with ``fruit_shapes: union`` each shape's SDF is evaluated only within
# this of its box (``collision.UnionSdf``'s pad; farther, the box distance, a
# lower bound, stands in): the distances are exact below it, so the checks'
# margins must stay below it. Smaller than the estimates' 5 cm: on a plant
# the boxes of several fruits' sets are large (``context.FruitObstacle``).
FRUIT_SET_PAD = 0.03


# A ``planner:`` value is wrong: ``key`` (the key path, e.g.
# ``planner.num_grasps``) and ``detail`` (what is wrong with it).
PlannerConfigError = ConfigError


# Value rules: field -> rule. Rules: ">0", ">=0", ">=1", "(lo,hi)" /
# "[lo,hi]" (open / closed ends), "finite"; "Nx<rule>" = a list of N values
# each obeying <rule>, "+x<rule>" = a non-empty list (the scenario's own
# rules read the same: ``lmap_drake.config_checks``).
_RULES = {
    "num_grasps": ">=1",
    "grasp_inset": ">=0",
    "num_directions": "[1,14]",
    "max_branch_angle_deg": "(0,180]",
    "distances": "+x>0",
    "early_stop_fraction": "(0,1]",
    "pregrasp_distance": ">0",
    "pregrasp_opening": "(0,0.085]",
    "release_opening": "[0,0.085]",
    "hidden_leaf_reach": "[0,0.1]",
    "ready_distances": "+x>=0",
    "grasp_close_width": "[0,0.085]",
    "gripper_close_speed": ">0",
    "grasp_attach_opening": "[0,0.085]",
    "min_branch_distance": ">=0",
    "min_usable_grasps": ">=0",
    "petiole_torsion_ratio": ">=0",
    "max_tether_elongation": ">=0",
    "max_pull_distance": ">=0",
    "arc_lever_reference": ">=0",
    "hinge_error": ">=0",
    "max_hinge_misfit": ">=0",
    "visibility_voxel": ">0",
    "collision_margin": ">=0",
    "robot_fruit_margin": ">=0",
    "max_brush_displacement": "[0,0.05]",
    "energy_weight": ">=0",
    "max_energy_per_node": ">=0",
    "speed_scale": "(0,1]",
    "approach_speed": ">0",
    "return_speed_scale": ">0",
    "max_pull_force": ">=0",
    "max_retreat_force": ">=0",
    "arc_angles_deg": "+x>0",
    "twist_angles_deg": "+x>0",
    "num_arc_axes": ">=1",
    "max_replans": ">=0",
    "max_reveals_per_fruit": ">=1",
    "next_leaf_min_gain": "[0,1]",
    "min_replan_gain": "[0,1]",
    "min_visibility_gain": "[0,1]",
    "min_fruit_confidence": "[0,1]",
    "hinge_bending_weight": ">=0",
    "max_hinge_deg": "(0,180]",
    "max_replan_turn_deg": "(0,180]",
}
_ENUMS = {
    "method": ("lmap", "random", "upward", "min_overlap"),
    "targets": ("largest", "all"),
    "fruit_shapes": ("union", "estimate"),
    "visibility_shapes": ("expected", "estimate"),
}
FAMILIES = ("pull", "arc", "twist")     # deformation.action.FAMILIES


def ValidatePlannerConfig(cfg: PlannerConfig, prefix: str = "planner") -> None:
    """Checks the values the type system cannot (ranges, enumerations, list
    contents, consistency); raises ``PlannerConfigError`` naming the key
    path (``prefix``.field) at the first wrong value."""
    def need(cond, name: str, msg: str):
        if not cond:
            raise PlannerConfigError(f"{prefix}.{name}", msg)

    CheckRules(cfg, prefix, _RULES, _ENUMS)
    fams = list(cfg.action_families)
    need(bool(fams) and all(f in FAMILIES for f in fams) and len(set(fams)) == len(fams),
         "action_families",
         f"must be a non-empty list of distinct families of 'pull', 'arc', 'twist', "
         f"got {fams}")
    cont = list(cfg.continuation_families)
    need(all(f in FAMILIES for f in cont) and len(set(cont)) == len(cont),
         "continuation_families",
         f"must be a list of distinct families of 'pull', 'arc', 'twist', got {cont}")
    need(all(0 < a < 180 for a in cfg.arc_angles_deg), "arc_angles_deg",
         f"must be angles in (0, 180) degrees, got {list(cfg.arc_angles_deg)}")
    need(all(0 < a < 180 for a in cfg.twist_angles_deg), "twist_angles_deg",
         f"must be angles in (0, 180) degrees, got {list(cfg.twist_angles_deg)}")
    need(all(0 < d < 0.1 for d in cfg.deeper_grasp_insets), "deeper_grasp_insets",
         f"must be insets in (0, 0.1) m, got {list(cfg.deeper_grasp_insets)}")
    # below 3 mm the pads would stay within a digital twin's 2 mm release
    # band and within the way out's 1 mm wait tolerance of the leaf
    need(cfg.release_opening == 0.0 or cfg.release_opening >= 0.003, "release_opening",
         f"must be 0 (the approach's opening) or at least 0.003 m past the leaf, "
         f"got {cfg.release_opening:g}")
    fa = cfg.force_action
    need(len(fa) in (0, 3) and (not fa or (float(fa[0]).is_integer() and
                                           float(fa[1]).is_integer() and fa[2] > 0)),
         "force_action", "must be empty or [grasp_id, direction_id, distance m], "
         f"got {list(fa)}")
    need(not fa or cfg.method == "lmap", "force_action",
         f"picks an LMAP candidate: it needs {prefix}.method 'lmap'")
    for key in ("collision_margin", "robot_fruit_margin"):
        need(cfg.fruit_shapes != "union" or getattr(cfg, key) < FRUIT_SET_PAD - 0.001, key,
             f"must be below {FRUIT_SET_PAD - 0.001:g} m with {prefix}.fruit_shapes 'union' "
             f"(the fruit distances are exact up to {FRUIT_SET_PAD:g} m), "
             f"got {getattr(cfg, key):g}")
