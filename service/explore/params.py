"""Exploration and control parameters (:class:`ExploreParams`): metres, seconds, radians."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class ExploreParams:
    """Exploration and control parameters (m, s, rad). Defaults fit a Pioneer 2DX with an LMS200."""

    #: m. Targets stay this far inside the ASR boundary: the P2DX sweeps a 0.37 m circle turning on
    #: the spot (rear corners at 0.301 m behind, 0.2125 m aside), plus margin for localisation.
    clearance: float = 0.45
    #: m. Unknown runs shorter than this are ignored: they cannot hide a gap the robot passes.
    min_unknown: float = 0.5
    #: m. Unknown runs are cut into regions at most this long, each looked at on its own.
    region_length: float = 2.0
    #: m. An unknown region this close to one already looked at is not visited again.
    visit_radius: float = 1.0
    #: m. An unknown region within this distance, in the laser's field of view, counts as seen.
    look_distance: float = 2.5
    #: rad. ... where "in the field of view" is within this of straight ahead (the LMS sees ±90°;
    #: the margin keeps regions grazed at the edge of the sweep for a proper look).
    view_half_angle: float = math.radians(70.0)
    #: m. A target is reached within this distance.
    arrive_tol: float = 0.3
    #: rad. Facing a direction within this counts as facing it.
    face_tol: float = 0.3
    #: m. Exits narrower than this are not driven through. The mapper keeps gaps from its
    #: ``passage_width`` (0.6 m) up; the P2DX is 0.425 m wide and sweeps a 0.37 m circle turning,
    #: so a 0.6-0.7 m gap (a slot between a table and a wall) can be entered only straight on, and
    #: lining up for one in a corner pinned the robot there (simulated ``aliasing``, seeds 1, 2 and
    #: 4: room A's or room B's table slot, hundreds of contacts, the last goals given up stuck).
    #: Doorways (0.9 m) and the passages round furniture are wider.
    min_exit_width: float = 0.7
    #: m. Exits are approached from this far inside, on the exit's normal, then driven through ...
    stage_distance: float = 0.8
    #: m. ... to this far beyond its midpoint.
    through_distance: float = 1.0
    #: m, s. An exit is given up once the robot, facing the point beyond it, sees a surface on
    #: the straight way there less than ``through_past`` beyond the exit line, for this long
    #: (the mapper sees a crossing only once the robot is outside the ASR).
    through_past: float = 0.3
    through_blocked_time: float = 1.0
    #: m, m, count. An exit is shut when this many scan returns lie in the strip ``shut_depth``
    #: deep just behind it on its normal, ``shut_width`` wide (the robot's width less margins:
    #: a jamb of a doorway approached off its axis stays outside).
    shut_depth: float = 0.3
    shut_width: float = 0.3
    shut_points: int = 3
    #: m. A run of exit edges whose ends run on within ``grazing_offset`` of the line of the surface
    #: beside them is crossed through what is left between those arms, when that is at least
    #: ``min_opening`` wide (:func:`crossing`).
    grazing_offset: float = 0.1
    min_opening: float = 0.5
    #: s. After reaching the far side, the mapper has this long to report the crossing.
    crossing_grace: float = 3.0
    #: m. After a crossing the robot carries on to the point beyond the exit (when it is at least
    #: this far): a new ASR planned from one view at its doorstep is mostly unknown.
    settle_min: float = 0.3
    #: m/s, rad/s. Speed limits: well inside the P2DX's 2.2 m/s / 500 °/s, slow enough for 5 Hz scans.
    v_max: float = 0.4
    w_max: float = 0.8
    #: 1/s. Heading gain of the path follower.
    k_heading: float = 1.5
    #: rad. Heading errors above this are turned away on the spot before driving.
    turn_in_place: float = 0.6
    #: m. Steering looks this far ahead for a free heading.
    lookahead: float = 1.0
    #: m. Paths inside the ASR: a grid of this cell size over the ASR polygon shrunk by
    #: ``path_clearance`` (the robot's half width and a margin), searched when the straight line
    #: to a target leaves it; the robot steers to the path point ``path_lookahead`` ahead, and
    #: plans again every ``replan_time`` s (the polygon grows) or when it is off the path.
    path_cell: float = 0.1
    path_clearance: float = 0.3
    path_lookahead: float = 0.8
    replan_time: float = 3.0
    #: m. Scan points (the last ``memory_time`` s) within this of the robot are taken out of the
    #: area a path is planned through, so a polygon drawn across a wall (drift between ASRs, a
    #: view seen through a gap) cannot route the robot into what the laser sees now. 0: off.
    path_obstacle_reach: float = 4.0
    #: m. Lateral margin added to the robot's half width when judging a heading free (steering).
    steer_margin: float = 0.12
    #: m. Lateral margin of the safety stop's corridor, and of steering through a doorway (0.9 m
    #: doors leave 0.24 m a side).
    avoid_margin: float = 0.05
    #: m. A scan point closer than this to the turning centre blocks turning on the spot: the
    #: P2DX's rear corners sweep 0.368 m. Points seen in the last ``memory_time`` s count too,
    #: carried along with the robot's pose, since the laser cannot see what is beside or behind.
    turn_radius: float = 0.41
    memory_time: float = 5.0
    #: m. Safety stop: no forward motion while a surface in the robot's path is closer to the laser.
    stop_distance: float = 0.3
    #: m. Forward speed falls linearly to zero over this distance before the stop distance.
    slow_zone: float = 0.5
    #: s, m. Stuck: the distance to the goal has not shrunk by ``progress_min`` for ``stuck_time``.
    stuck_time: float = 12.0
    progress_min: float = 0.15
    #: s. A goal whose way stays shut by the safety stop this long is given up.
    blocked_time: float = 4.0
    #: s. A stall reported within this of a change of the motion's direction belongs to the motion
    #: before: the P2OS stall bits come with the 10 Hz SIP, and a robot pressed against a wall still
    #: reports the stall in the first SIP after it was told to pull away. Taken as the new move's,
    #: every escape move was dropped at once (aliasing seed 2 sat wedged in a corner for 200 s).
    stall_grace: float = 0.3
    #: s. A goal not achieved in this time is given up (bounds exploration whatever happens).
    goal_timeout: float = 120.0
    #: m, m/s, rad. Recovery: move ``recovery_distance`` at ``recovery_speed``, then turn ``recovery_turn``.
    recovery_distance: float = 0.25
    recovery_speed: float = 0.15
    recovery_turn: float = 1.2
    #: How many times exits that failed are all forgotten and tried again before exploration ends.
    retries: int = 2
    #: Before it is done (nothing left, or the last retry round out of time), visit once every
    #: unknown region that was only looked at from afar (:meth:`Planner.observe`): driven to and
    #: faced, each in turn, the robot routed to their ASRs over the topological map; the round is
    #: bounded like a retry round (``retry_budget``). Entered also from a retry round out of time,
    #: `lab` 0-19 closed 62 of 72 loops (13 runs meeting the whole goal) where entered only when
    #: nothing was left 57 of 68 (12), and without the round 55 of 66 (12). A look
    #: from afar retires a region that stays unknown without a trip to it, and most such regions
    #: are space behind furniture; but a look past a chair's legs can see nothing of what they
    #: hide. With range noise σ 0.0101 m instead of 0.0100, `aliasing` seed 0 declared exploration
    #: complete 6 s after the start, in the first ASR (a pocket of room A bounded by a chair, its
    #: one exit 0.69 m wide, under ``min_exit_width``), two of its three regions never entered.
    visit_round: bool = True
    #: s. A retry round ends (and with it exploration) after this long without new space (an ASR
    #: whose centre no earlier ASR covers: a retried exit that led somewhere new restarts the
    #: clock). Most exits still open when the first round ends point into a wall or a table (in
    #: `lab` the wall 0-0.3 m behind them); driven at one by one they ran out the hour in `lab`
    #: seeds 1-2 and `aliasing`. Without retries `office` seed 0 and `aliasing` seed 2 missed a room
    #: that a retry round finds. Without the restart, `lab` seed 3 ended while the retry round was
    #: still finding new ASRs, three regions unentered.
    retry_budget: float = 300.0
    #: An exit (or backtrack through it) chosen this many times in one round fails: the robot
    #: goes round in a loop (its far side sends it back, the mapper flips between two ASRs).
    max_attempts: int = 4
    #: s. Choices of one exit goal closer together than this count as one attempt.
    attempt_spacing: float = 10.0
    #: m. Exits of a duplicate and of its matched ASR within this distance (global frame) are one exit.
    duplicate_radius: float = 1.0
    #: m. An exit needs no visit when the space beyond it is already mapped: the points this far
    #: beyond it (beyond the ASR polygon, on the exit's normal) all lie inside other ASRs (global
    #: frame, shrunk by ``known_margin``). In an open-plan room every gap between tables is an exit
    #: into the same room.
    known_depths: tuple[float, ...] = (0.5, 1.0, 1.5)
    known_margin: float = 0.2
    #: Or: at least this fraction of the strip beyond the exit (its width, ``max(known_depths)``
    #: deep) lies inside the other ASRs' polygons (global frame, as they are). A long exit across an
    #: open-plan room, or one beside a seam between two ASRs, has points outside any one ASR shrunk
    #: by ``known_margin`` although every bit of the space beyond it is mapped.
    known_cover: float = 0.7
    #: m. An unknown region needs no look when the space round it (this far from its midpoint,
    #: outside the ASR) is ``known_cover`` inside other ASRs.
    known_radius: float = 0.75
    #: m, robot frame. Robot front (from the turning centre), half width, laser position.
    front: float = 0.210
    half_width: float = 0.2125
    laser_x: float = 0.017
    laser_y: float = 0.008
    #: Close loops actively (beyond method.md §8): once the current ASR has nothing left to look
    #: at and no unexplored exit, the robot crosses one of its exits before it backtracks, if one
    #: has no link and leads into space that other ASRs hold, none of them within
    #: ``close_min_hops`` - 1 links. Such an exit counts as explored (the space beyond is known),
    #: but crossing it makes a new ASR there (or re-enters one) whose cycle check can close the
    #: loop, and links the two places for backtracking. Without it, `lab` seed 3 backed out of a
    #: 6.7 m² piece whose centre lay in the 62 m² first ASR (the centre crosscheck held one way
    #: only) and the loop round the north table island stayed open; held-out `lab` seed 12 flipped
    #: between two ASRs at a corridor corner with no link back and left a region unentered. At
    #: most ``close_per_asr`` such crossings per ASR, none from a duplicate.
    close_loops: bool = True
    close_min_hops: int = 3
    #: How many such crossings may follow one another, each from the ASR the one before made (when
    #: that ASR matched nothing: a match makes it a duplicate, which makes none); 1: an ASR such a
    #: crossing made makes none. A new ASR in known space that matched nothing has unlinked exits
    #: into known space of its own, and each crossing further along makes one more ASR there for
    #: the cycle check; with 1, a robot whose one crossing matched nothing backtracked, the loop
    #: left open. 3 against 1 over `lab` 0-39: whole goal 26 against 20 runs, loops closed 152 of
    #: 169 against 132 of 153, no false closure (docs/measurement-history.md); chains of two are common
    #: (four in `lab` seed 10), of three rare.
    close_chain: int = 3
    #: How many exits of one ASR may be so crossed, each into known space held by ASRs not within
    #: ``close_min_hops`` - 1 links (those of the crossings before count as linked). 1 left `lab`
    #: seed 1's south corridor ASR, whose crossing into the room had matched, with its west end
    #: inside the corner piece of the west corridor unlinked and the loop through the corridor open.
    #: Stepped `lab` 0-59 with 2 (and each crossing counted when made, not when planned): whole
    #: goal 42 of 60 runs against 40, loops 244 of 258 against 224 of 244, no false closure
    #: against one (docs/measurement-history.md).
    close_per_asr: int = 2
    #: A doorway merged into the way back (README, "Known faults"): when the doorway's exit edges
    #: run on round a corner into the gap the robot came in by, the ASR's exit is the whole run, one
    #: chord, linked back where the robot came from, and the doorway is never a target (`aliasing`
    #: seed 8 ended after 250 s in room A, the corridor and room B unentered). With this on, a last
    #: round (after the visiting round, bounded like it by ``retry_budget``) cuts each linked exit's
    #: run where it turns more than ``side_turn`` (rad) from one edge to the next, and each straight
    #: piece at least ``min_exit_width`` long whose space beyond is not known (``known_depths``) is
    #: an exit of its own (:func:`side_openings`). Only the explorer cuts: the mapper's exits, and
    #: so the replays of the logs, are unchanged; the robot going through the piece leaves the ASR
    #: where no exit chord is, and the mapper opens an exit there. Offered from the start instead
    #: of in a last round, the pieces changed the `lab` runs' paths (one false closure, `lab` seed
    #: 15, in the first 13 runs).
    side_openings: bool = True
    side_turn: float = math.radians(60.0)
