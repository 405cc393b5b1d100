"""The controller (:class:`Explorer`): turns the planner's goals into velocity commands from the
latest scan, with the laser safety stop, stuck detection and recovery; see :mod:`service.explore`."""

from __future__ import annotations

import logging
import math
from collections import deque

import numpy as np
import shapely

from mapper.exits import segment_distance
from mapper.se2 import Pose, compose, inverse, transform_points, wrap
from mapper.types import ASR
from service.explore.links import exit_of
from service.explore.params import ExploreParams
from service.explore.paths import plan_path
from service.explore.planner import Planner
from service.explore.regions import shape_key
from service.explore.safety import Command, free_distance, safety_limit
from service.explore.view import Goal, MapView, place_of

log = logging.getLogger(__name__)


class Explorer:
    """The exploration behaviour: call :meth:`step` with the mapper's view and the latest scan
    points (robot frame) at time ``t`` (s); it returns the velocity command for now."""

    def __init__(self, params: ExploreParams | None = None) -> None:
        self.p = params or ExploreParams()
        self.planner = Planner(self.p)
        self.goal: Goal | None = None
        self.phase = ""
        self._goal_t = 0.0
        self._best = math.inf
        self._best_t = 0.0
        self._reached_t: float | None = None
        self._recovery: list[tuple[float, float, float]] = []  # (duration s, v, w) still to run
        self._recovery_until = 0.0
        self._recovery_cmd = (0.0, 0.0)
        self._escaping = self._skipped = False
        self._blocked_since: float | None = None
        self._through_blocked_since: float | None = None
        self._memory: deque[tuple[float, Pose, np.ndarray]] = deque()
        self._near = np.zeros((0, 2))
        self._last: Command | None = None
        self._motion: tuple[float, float] = (0.0, 0.0)  # signs of the last command's v and w
        self._motion_since = -math.inf  # when the motion last changed direction (s)
        self._unjams: list[float] = []
        self._asr: ASR | None = None
        self._attempts: dict[tuple, tuple[int, float]] = {}
        self._turn_sign = 0.0
        self._view: MapView | None = None
        self._area_key: tuple | None = None
        self._area: shapely.Geometry = shapely.Polygon()
        self._t = 0.0
        self._path: np.ndarray | None = None
        self._path_key: tuple | None = None
        self._path_t = -math.inf
        self.finished = False
        self._retry_round, self._retry_start = 0, 0.0  # the planner's retry round, and when it began
        self._newest_asr = -1  # the newest ASR id _new_space has seen
        self._last_current: int | None = None  # the current ASR at the last step
        self._last_newest = -1  # the newest ASR id at the last step (ids only grow)
        self.counts = {"goals": 0, "unknown": 0, "exits": 0, "backtracks": 0, "stuck": 0, "failed": 0,
                       "unjam": 0}

    # -- goal life cycle ---------------------------------------------------------------------------
    def _set_goal(self, goal: Goal, t: float) -> None:
        self.goal = goal
        self.phase = "approach"
        self._goal_t = t
        self._best = math.inf
        self._best_t = t
        self._reached_t = None
        self._through_blocked_since = None
        if goal.kind in ("unknown", "exit", "close", "backtrack", "goto"):
            self.counts["goals"] += 1
            kind = {"unknown": "unknown", "exit": "exits", "close": "exits", "backtrack": "backtracks",
                    "goto": "backtracks"}
            self.counts[kind[goal.kind]] += 1
            log.debug("goal %s", goal)

    def _too_often(self, goal: Goal) -> bool:
        """Count the choice of an exit goal; True once it was chosen ``max_attempts`` times this round."""
        if goal.kind not in ("exit", "close", "backtrack", "goto") or goal.exit is None or goal.asr is None:
            return False
        key = (self.planner.memory.retries, goal.path[-1] if goal.kind == "goto" else goal.asr, goal.exit)
        return self._attempt(key) > self.p.max_attempts

    def _attempt(self, key: tuple) -> int:
        """Count an attempt at ``key`` now; returns the attempts so far. Attempts in quick succession
        (an unknown region came and went) are one; an attempt is timed from its first choice, or a
        chain of choices (the mapper flipping between two ASRs every second) would be one for ever."""
        n, start = self._attempts.get(key, (0, -math.inf))
        if self._t - start >= self.p.attempt_spacing:
            n, start = n + 1, self._t
        self._attempts[key] = (n, start)
        return n

    def _left_for_unknown(self, asr: ASR) -> None:
        """The robot left ``asr`` on its way to one of its unknown regions. Once it has done so
        ``max_attempts`` times in a round, the way to its regions leaves it (two ASRs of one space,
        each sending the robot into the other): its pending regions are given up, to be seen from
        elsewhere. A whole-stack `lab` run (seed 0) flipped so between ASRs 2 and 3 north of a table
        island for 800 s, giving up every exit of the map in turn, and ended with 1 of 7 regions
        entered."""
        if self._attempt((self.planner.memory.retries, "left", asr.id)) < self.p.max_attempts:
            return
        pending = self.planner.pending_unknown(asr)
        for m in pending:
            self.planner.looked_at(asr.id, m)
        if pending:
            self.counts["failed"] += 1
            log.info("exploration: gave up %d unknown regions of ASR %s (left it %d times on the way)",
                     len(pending), asr.id, self.p.max_attempts)

    def _give_up(self, why: str) -> None:
        g = self.goal
        if g is None:
            return
        self.counts["failed"] += 1
        log.info("exploration: gave up %s %s in ASR %s (%s)", g.kind, g.exit or g.look_at, g.asr, why)
        if g.kind == "unknown" and g.look_at is not None and g.asr is not None:
            self.planner.looked_at(g.asr, g.look_at)
        elif g.kind == "goto" and g.exit is not None:
            self.planner.failed(g.path[-1], g.exit, g.exit_mid)  # the far exit, in its ASR's frame
        elif g.exit is not None and g.asr is not None:
            self.planner.failed(g.asr, g.exit, g.exit_mid)
        self.goal = None

    def _still_valid(self, view: MapView) -> bool:
        g = self.goal
        if g is None or g.asr != view.current or g.asr not in view.asrs:
            return False
        asr = view.asrs[g.asr]
        if g.kind == "unknown":
            pending = self.planner.pending_unknown(asr)
            return any(math.hypot(q[0] - g.look_at[0], q[1] - g.look_at[1]) < self.p.visit_radius
                       for q in pending)
        if g.kind == "settle":
            return True
        if g.kind == "goto":
            other = view.asrs.get(g.path[-1])
            ex = next((e for e in other.exits if e.id == g.exit), None) if other is not None else None
            return ex is not None and not self.planner.explored(view, other, ex)  # type: ignore[arg-type]
        if g.kind in ("exit", "close", "backtrack"):
            ex = exit_of(view, asr, g.exit, self.p)  # type: ignore[arg-type]
            if ex is None:
                return False
            if g.kind == "exit":
                # An unknown region appearing first takes precedence (enclosure before exits).
                return not self.planner.explored(view, asr, ex) and not self.planner.pending_unknown(asr)
            if g.kind == "close":
                return (ex.to is None and not self.planner._failed(asr, ex)
                        and not self.planner.pending_unknown(asr))
            return True
        return False

    # -- the control step --------------------------------------------------------------------------
    def step(self, view: MapView, points: np.ndarray, t: float, stalled: bool = False) -> Command:
        """The command for now. ``points``: latest scan returns (N, 2) in the robot frame (m);
        ``stalled``: the robot reports stalled wheels (P2OS stall bits)."""
        self._near = self._remember(view, points, t)
        stalled = stalled and t - self._motion_since >= self.p.stall_grace
        self._last = self._command(view, points, t, stalled)
        motion = (float(np.sign(self._last.v)), float(np.sign(self._last.w)))
        if motion != self._motion:
            self._motion, self._motion_since = motion, t
        return self._last

    def _remember(self, view: MapView, points: np.ndarray, t: float) -> np.ndarray:
        """Scan points near the robot from the last ``memory_time`` s, in the robot frame now (m).

        The laser sees only ahead; what the robot passed is now beside or behind it, where its
        corners sweep when it turns. Points are kept in the global frame (the current ASR's origin
        composed with the pose); a jump of the global pose (re-entry into a drifted ASR) forgets them.
        """
        asr = view.asrs.get(view.current) if view.current is not None else None
        if asr is None:
            self._memory.clear()
            return points
        glob = compose(asr.origin, view.pose)
        if self._memory:
            prev = self._memory[-1][1]
            if math.hypot(glob[0] - prev[0], glob[1] - prev[1]) > 0.5:
                self._memory.clear()
        reach = 2.0 * self.p.turn_radius
        near = points[np.hypot(points[:, 0], points[:, 1]) < reach] if len(points) else points
        self._memory.append((t, glob, transform_points(glob, near) if len(near) else np.zeros((0, 2))))
        while self._memory and t - self._memory[0][0] > self.p.memory_time:
            self._memory.popleft()
        old = [m[2] for m in list(self._memory)[:-1] if len(m[2])]
        if not old:
            return points
        return np.vstack([points, transform_points(inverse(glob), np.vstack(old))])

    def _command(self, view: MapView, points: np.ndarray, t: float, stalled: bool) -> Command:
        last = self._last
        moving = last is not None and (last.v != 0.0 or last.w != 0.0)
        if stalled and moving and (self._recovery or t < self._recovery_until):
            self._recovery_until = t  # this recovery move is blocked too: on to the next one
            self._skipped = True
        elif stalled and moving:
            # Something the laser cannot see (behind, beside) blocks the motion: move clear the
            # other way and carry on with the same goal; a goal that keeps jamming is given up.
            self.counts["unjam"] += 1
            self._unjams = [u for u in self._unjams if t - u < self.p.stuck_time] + [t]
            if len(self._unjams) > 3:
                self._unjams = []
                return self._start_recovery(points, t)
            self._queue(self._escape(last, points), t, escape=True)
        if self._recovery or t < self._recovery_until:
            return self._recover(points, t)
        return self._step(view, points, t)

    def _step(self, view: MapView, points: np.ndarray, t: float) -> Command:
        self._t = t
        self._note_crossing(view)
        self._asr = view.asrs.get(view.current) if view.current is not None else None
        self._view = view
        if view.current in view.asrs:
            self.planner.observe(view.asrs[view.current], view.pose)
            self.planner.retire_known_unknown(view, view.asrs[view.current])
            self.planner.shut_exits(view, points)
        if not self._still_valid(view):
            goal = self._settle(view) or self.planner.plan(view)
            if self._too_often(goal):
                where = goal.path[-1] if goal.kind == "goto" else goal.asr
                self.planner.failed(where, goal.exit, goal.exit_mid)  # type: ignore[arg-type]
                log.info("exploration: gave up %s %s in ASR %s (chosen %d times)", goal.kind, goal.exit,
                         goal.asr, self.p.max_attempts)
                goal = self.planner.plan(view)
            self._set_goal(goal, t)
        mem = self.planner.memory
        if mem.retries != self._retry_round or self._new_space(view):
            self._retry_round, self._retry_start = mem.retries, t
        if mem.retries and self.goal is not None and self.goal.kind != "done" and (
            t - self._retry_start > self.p.retry_budget
        ):
            if self.planner.start_visiting() or self.planner.start_side_round(view):  # the next round
                log.info("exploration: retry round %d out of time (%.0f s)", mem.retries - 1,
                         self.p.retry_budget)
                self._retry_round, self._retry_start = mem.retries, t
                self._set_goal(self.planner.plan(view), t)
            else:
                log.info("exploration: retry round %d out of time (%.0f s): done", mem.retries,
                         self.p.retry_budget)
                self._set_goal(Goal("done", self.goal.asr), t)
        g = self.goal
        assert g is not None
        if g.kind == "done":
            self.finished = True
            return Command(0.0, 0.0, "done", done=True)
        if g.kind == "wait":
            return Command(0.0, 0.0, "waiting for the first ASR")
        self.finished = False
        if t - self._goal_t > self.p.goal_timeout:
            self._give_up("timeout")
            return Command(0.0, 0.0, "goal timed out")
        pose = view.pose
        if g.kind == "unknown":
            return self._unknown(g, pose, points, t)
        if g.kind == "settle":
            if math.hypot(g.target[0] - pose[0], g.target[1] - pose[1]) < self.p.arrive_tol:  # type: ignore[index]
                self.goal = None
                return Command(0.0, 0.0, "in the new ASR")
            return self._drive_to(g.target, pose, points, t, "into the new ASR")  # type: ignore[arg-type]
        return self._traverse(g, pose, points, t)

    def _note_crossing(self, view: MapView) -> None:
        """An unexplored exit just crossed (the robot was driving through it) into an ASR the map
        already held is explored (the mapper re-entered a known ASR without a transition through
        that exit, e.g. one the robot left elsewhere): else the planner sends the robot through
        it again and again (``office`` seed 0 spent 900 s so between two ASRs of one room, and
        never reached the last room)."""
        prev, self._last_current = self._last_current, view.current
        newest, self._last_newest = self._last_newest, max(view.asrs, default=-1)
        g = self.goal
        if (g is not None and g.kind == "close" and self.phase == "through" and g.asr == prev
                and view.current is not None and view.current != prev):
            # Counted once crossed: a closing goal given up for an unknown region that appeared
            # first is planned again (`lab` seed 29 counted its ASR 4's, gave it up 5 s later and
            # backtracked, the loop round the north table island open).
            mem = self.planner.memory
            mem.closing_from[prev] = mem.closing_from.get(prev, 0) + 1
            if view.current > newest:
                mem.closing_made[view.current] = mem.closing_made.get(prev, 0) + 1
        if (g is not None and g.kind == "unknown" and g.asr == prev and prev in view.asrs
                and view.current is not None and view.current != prev):
            self._left_for_unknown(view.asrs[prev])
        if (g is not None and g.kind == "exit" and self.phase == "through" and g.asr == prev
                and g.exit_mid is not None
                and view.current is not None and view.current != prev and view.current <= newest):
            self.planner.crossed_into_known(g.asr, g.exit_mid)
        if (g is not None and g.kind == "backtrack" and self.phase == "through" and g.asr == prev
                and g.exit is not None and len(g.path) > 1 and view.current is not None
                and view.current != prev and view.current <= newest
                and place_of(view, view.current) != place_of(view, g.path[1])):
            # The link does not lead where the route needs: crossing it again would only flip the
            # robot between the two ASRs (``lab`` seed 4 and the stack's run 2, until the exit had
            # been chosen ``max_attempts`` times, and again in each retry round).
            self.planner.failed(g.asr, g.exit, g.exit_mid)
            log.info("exploration: backtrack %s of ASR %s led into ASR %s, not %s: not taken again",
                     g.exit, g.asr, view.current, g.path[1])

    def _new_space(self, view: MapView) -> bool:
        """Whether the map has gained an ASR whose centre (global frame) lies inside no earlier ASR
        since the last call: new space, not another ASR of space already known."""
        ids = sorted(view.asrs)
        fresh = [k for k in ids if k > self._newest_asr]
        if not fresh:
            return False
        self._newest_asr = ids[-1]
        polygons = self.planner._known_polygons(view)  # global frame, cached for the planner
        for k in fresh:
            a = view.asrs[k]
            c = transform_points(a.origin, np.array([a.centre]))[0]
            if not any(shapely.contains_xy(g, c[0], c[1]) for o, g in polygons if o < k):
                return True
        return False

    def _settle(self, view: MapView) -> Goal | None:
        """After a crossing (the goal was an exit of another ASR), the point beyond that exit in the
        new ASR's frame, through the global frame both ASRs are placed in; none when that point
        lies outside the new ASR (drift, or a notch the new ASR's gates cut round the exit): driving
        there would only leave the new ASR again (``lab`` seed 15 flipped so between two ASRs for
        200 s)."""
        g = self.goal
        if (g is None or g.kind not in ("exit", "close", "backtrack") or self.phase != "through"
                or g.through is None or g.asr not in view.asrs or view.current not in view.asrs
                or g.asr == view.current):
            return None
        old, new = view.asrs[g.asr], view.asrs[view.current]
        glob = transform_points(old.origin, np.array([g.through]))
        local = transform_points(inverse(new.origin), glob)[0]
        if math.hypot(local[0] - view.pose[0], local[1] - view.pose[1]) < self.p.settle_min:
            return None
        if len(new.boundary) >= 3 and not shapely.contains_xy(new.polygon, float(local[0]), float(local[1])):
            return None
        return Goal("settle", new.id, target=(float(local[0]), float(local[1])))

    def _unknown(self, g: Goal, pose: Pose, points: np.ndarray, t: float) -> Command:
        lx, ly = g.look_at  # type: ignore[misc]
        d_look = math.hypot(lx - pose[0], ly - pose[1])
        bearing = wrap(math.atan2(ly - pose[1], lx - pose[0]) - pose[2])
        from_afar = d_look < self.p.look_distance and abs(bearing) < self.p.face_tol
        if from_afar and not self.planner.memory.visiting:  # the visiting round goes all the way
            self.planner.looked_at(g.asr, g.look_at)  # type: ignore[arg-type]
            self.goal = None
            return Command(0.0, 0.0, "looked at an unknown region")
        dist = math.hypot(g.target[0] - pose[0], g.target[1] - pose[1])  # type: ignore[index]
        if dist < self.p.arrive_tol or self.phase == "face":
            self.phase = "face"
            if abs(bearing) < self.p.face_tol:
                self.planner.looked_at(g.asr, g.look_at)  # type: ignore[arg-type]
                self.goal = None
                return Command(0.0, 0.0, "looked at an unknown region")
            return self._rotate(bearing, points, t, "facing an unknown region")
        return self._drive_to(g.target, pose, points, t, "to an unknown region")  # type: ignore[arg-type]

    def _traverse(self, g: Goal, pose: Pose, points: np.ndarray, t: float) -> Command:
        what = {"exit": "through exit", "close": "closing a loop through exit"}.get(
            g.kind, "backtracking through exit")
        if self.phase == "approach":
            dist = math.hypot(g.target[0] - pose[0], g.target[1] - pose[1])  # type: ignore[index]
            if dist < self.p.arrive_tol:
                self.phase = "through"
                self._best = math.inf
                self._best_t = t
            else:
                return self._drive_to(g.target, pose, points, t, f"to exit {g.exit}")  # type: ignore[arg-type]
        dist = math.hypot(g.through[0] - pose[0], g.through[1] - pose[1])  # type: ignore[index]
        if dist < self.p.arrive_tol or self._reached_t is not None:
            # On the far side but the mapper has not switched ASR (yet).
            if self._reached_t is None:
                self._reached_t = t
            if t - self._reached_t > self.p.crossing_grace:
                self._give_up("crossed but the mapper stayed in the ASR")
            return Command(0.0, 0.0, f"waiting for the crossing of {g.exit}")
        # Doorways leave ~0.24 m a side: steer with a tight margin so the jambs do not repel the robot
        # (only near the exit: a far one, ``goto``, is driven to with the usual margin).
        near = dist < self.p.stage_distance + self.p.through_distance + 0.5
        if near and self._no_way_through(g.through, pose, points, t):  # type: ignore[arg-type]
            self._give_up("a surface across the way through")
            return Command(0.0, 0.0, f"no way through exit {g.exit}")
        return self._drive_to(g.through, pose, points, t, f"{what} {g.exit}",  # type: ignore[arg-type]
                              margin=0.02 if near else None)

    def _no_way_through(self, through: tuple[float, float], pose: Pose, points: np.ndarray, t: float) -> bool:
        """Whether the scan shows a surface across the straight way to ``through`` (ASR frame) short
        of ``through_past`` beyond the exit, for ``through_blocked_time`` s while the robot faces it:
        an exit that is no gap (a chord from a door jamb diagonally across a corridor, its far side
        behind a wall) is given up at once instead of after ``stuck_time`` against the wall."""
        p = self.p
        dist = math.hypot(through[0] - pose[0], through[1] - pose[1])
        bearing = wrap(math.atan2(through[1] - pose[1], through[0] - pose[0]) - pose[2])
        if abs(bearing) > p.face_tol or not len(points):
            self._through_blocked_since = None
            return False
        need = max(p.through_past, dist - p.through_distance + p.through_past)
        # A body narrower than the robot's: one that stopped short of the staging point, off the
        # doorway's axis, still sees a jamb clip the straight way through a real doorway.
        free = float(free_distance(points, np.array([bearing]), p, -0.1)[0]) + p.front
        if free >= need:
            self._through_blocked_since = None
            return False
        if self._through_blocked_since is None:
            self._through_blocked_since = t
        return t - self._through_blocked_since >= p.through_blocked_time

    def _seen(self, points: np.ndarray) -> np.ndarray:
        """The scan ``points`` with those remembered from the last ``memory_time`` s (robot frame,
        m; :meth:`_remember`), or ``points`` alone when the memory is not of this step."""
        return self._near if len(self._near) >= len(points) else points

    def _rotate(self, bearing: float, points: np.ndarray, t: float, status: str,
                track: bool = True) -> Command:
        """Turn on the spot by ``bearing`` (rad), backing off first if a surface is within the sweep."""
        if track:
            self._progress(abs(bearing), t)
            if self._stuck(t):
                return self._start_recovery(points, t)
        pts = self._seen(points)
        near = pts[np.hypot(pts[:, 0], pts[:, 1]) < self.p.turn_radius] if len(pts) else pts
        creep = 0.5 * self.p.recovery_speed
        if len(near) and (near[:, 0] > 0.0).all():
            return Command(-creep, 0.0, f"{status} (backing off to turn)")
        if len(near) and (near[:, 0] < 0.0).all() and self._front_free(points):
            return Command(creep, 0.0, f"{status} (moving off to turn)")
        if abs(bearing) > 0.8 * math.pi and self._turn_sign:
            # Nearly behind: keep turning the way it was turning, or noise flips the side each step
            # and the robot stands still.
            bearing = math.copysign(abs(bearing), self._turn_sign)
        w = float(np.clip(self.p.k_heading * bearing, -self.p.w_max, self.p.w_max))
        if abs(w) < 0.15:
            w = math.copysign(0.15, bearing)  # below this P2OS barely turns (1 deg/s resolution)
        self._turn_sign = math.copysign(1.0, w)
        return Command(0.0, w, status)

    def _drive_to(self, target: tuple[float, float], pose: Pose, points: np.ndarray, t: float,
                  status: str, margin: float | None = None) -> Command:
        dist = math.hypot(target[0] - pose[0], target[1] - pose[1])
        aim, remaining = self._aim(target, pose, t, self._seen(points))
        self._progress(remaining, t)
        if self._stuck(t):
            return self._start_recovery(points, t)
        dx, dy = aim[0] - pose[0], aim[1] - pose[1]
        want = wrap(math.atan2(dy, dx) - pose[2])
        margin = self.p.steer_margin if margin is None else margin
        heading = self._steer(want, math.hypot(dx, dy), points, margin)
        if heading is None:
            # Nothing free towards the target: turn towards it and let stuck detection decide.
            return self._rotate(want, points, t, f"{status} (blocked)", track=False)
        if abs(heading) > self.p.turn_in_place:
            return self._rotate(heading, points, t, status, track=False)
        w = float(np.clip(self.p.k_heading * heading, -self.p.w_max, self.p.w_max))
        v = self.p.v_max * math.cos(heading) * min(1.0, dist / 0.6 + 0.2)
        v = safety_limit(points, v, self.p)
        if v > 0.0:
            self._blocked_since = None
            return Command(v, w, status)
        # The way ahead stays shut (a target behind a wall, a doorway that is not one): give it up.
        if self._blocked_since is None:
            self._blocked_since = t
        elif t - self._blocked_since > self.p.blocked_time:
            self._blocked_since = None
            return self._start_recovery(points, t)
        return Command(0.0, w, f"{status} (safety stop)")

    def _aim(self, target: tuple[float, float], pose: Pose, t: float,
             points: np.ndarray) -> tuple[tuple[float, float], float]:
        """Where to steer now on the way to ``target`` (ASR frame), and the distance left (m): the
        target itself when the straight line to it stays inside the ASR, shrunk by the robot's
        half width, else a point ``path_lookahead`` along a path planned inside the ASR (from the
        free cells nearest the robot and the target, which may lie outside it: a robot beside a
        wall, a target beyond an exit). No path found: the target itself. ``points`` (robot frame,
        m): what the laser sees, kept out of the path (``path_obstacle_reach``)."""
        p = self.p
        direct = (target, math.hypot(target[0] - pose[0], target[1] - pose[1]))
        asr = self._asr
        if asr is None or len(asr.boundary) < 3 or direct[1] < p.path_lookahead:
            self._path = None
            return direct
        key = (asr.id, target)
        if key != self._path_key or t - self._path_t > p.replan_time or self._off_path(pose):
            self._path_key, self._path_t = key, t
            self._path = None
            far = self.goal is not None and self.goal.kind == "goto" and self._view is not None
            # A far exit (goto) is reached through the whole map: every ASR, in this one's frame.
            poly = self._map_area(self._view, asr) if far else shapely.make_valid(asr.polygon)
            seen = np.zeros((0, 2))
            if p.path_obstacle_reach > 0.0 and len(points):
                near = points[np.hypot(points[:, 0], points[:, 1]) < p.path_obstacle_reach]
                seen = transform_points(pose, near) if len(near) else seen
            inner = poly.buffer(-p.half_width)
            line = shapely.LineString([pose[:2], target])
            blocked = len(seen) and segment_distance(seen[:, 0], seen[:, 1],
                                                     np.array([pose[:2], target])).min() < p.half_width
            if blocked or not inner.covers(line):
                self._path = plan_path(poly, (pose[0], pose[1]), target, p.path_cell, p.path_clearance,
                                       seen)
        path = self._path
        if path is None or len(path) < 2:
            return direct
        d = np.hypot(path[:, 0] - pose[0], path[:, 1] - pose[1])
        k = int(np.argmin(d))
        seg = np.hypot(*np.diff(path[k:], axis=0).T)
        along = np.concatenate([[0.0], np.cumsum(seg)])
        j = k + int(np.searchsorted(along, p.path_lookahead))
        aim = path[min(j, len(path) - 1)]
        left = float(d[k] + along[-1]) + math.hypot(target[0] - path[-1, 0], target[1] - path[-1, 1])
        return (float(aim[0]), float(aim[1])), left

    def _map_area(self, view: MapView, asr: ASR) -> shapely.Geometry:
        """Every ASR's polygon in ``asr``'s frame, each grown by a little so that neighbours meet
        at their common exits, as one area, less ``asr``'s own surfaces (cached while the ASRs stay
        the same). Drifted neighbours overlap across walls; the current ASR's walls, seen in its own
        frame, are where they are, so a path out of it leaves through its exits."""
        shapes = tuple((a.id, shape_key(a), tuple(a.origin)) for a in view.asrs.values())
        key = (asr.id, tuple(asr.edges), shapes)
        if self._area_key != key:
            to_here = inverse(asr.origin)
            parts = [shapely.make_valid(shapely.Polygon(transform_points(compose(to_here, a.origin),
                                                                         np.asarray(a.boundary))))
                     for a in view.asrs.values() if len(a.boundary) >= 3]
            area = shapely.union_all([q.buffer(0.05) for q in parts]) if parts else shapely.Polygon()
            b = np.asarray(asr.boundary, dtype=float)
            walls = [shapely.LineString([b[i], b[(i + 1) % len(b)]])
                     for i, e in enumerate(asr.edges) if e == "surface" and len(b) >= 3]
            if walls:
                area = area.difference(shapely.union_all(walls).buffer(0.05))
            self._area, self._area_key = area, key
        return self._area

    def _off_path(self, pose: Pose) -> bool:
        path = self._path
        if path is None:
            return False
        return float(np.hypot(path[:, 0] - pose[0], path[:, 1] - pose[1]).min()) > 2.0 * self.p.path_lookahead

    def _steer(self, want: float, dist: float, points: np.ndarray, margin: float) -> float | None:
        """The heading (rad, robot frame) nearest ``want`` along which the way is free for
        min(dist, lookahead) m; None when no heading within 100° of ``want`` is."""
        need = min(dist, self.p.lookahead)
        cands = want + np.radians(np.concatenate([[0.0], np.repeat(np.arange(5, 101, 5), 2)
                                                  * np.tile([1, -1], 20)]))
        free = free_distance(points, cands, self.p, margin)
        ok = free >= need
        if not ok.any():
            return None
        return float(wrap(cands[int(np.argmax(ok))]))

    # -- stuck detection and recovery ------------------------------------------------------------
    def _progress(self, measure: float, t: float) -> None:
        if measure < self._best - self.p.progress_min:
            self._best = measure
            self._best_t = t
        elif self._best == math.inf:
            self._best, self._best_t = measure, t

    def _stuck(self, t: float) -> bool:
        return t - self._best_t > self.p.stuck_time

    def _turn_blocked(self) -> bool:
        near = self._near
        return bool(len(near) and float(np.hypot(near[:, 0], near[:, 1]).min()) < self.p.turn_radius)

    def _front_free(self, points: np.ndarray) -> bool:
        if not len(points):
            return True
        front = free_distance(points, np.array([0.0]), self.p, self.p.avoid_margin)[0]
        return bool(front > self.p.recovery_distance + self.p.stop_distance)

    def _escape(self, last: Command, points: np.ndarray) -> list[tuple[float, float, float]]:
        """Moves to try, in turn, to get clear of a contact (the first that does not stall wins).

        A blocked translation: away from it first, then turning either way, then the other
        translation. A blocked turn (a rear corner swept into something): forward, then back,
        and only then turning back the way it came, which always succeeds and so ends the escape
        where the turn will jam again (``aliasing`` seeds 1 and 5 ended so, turning to and fro
        against chair legs and a corner behind for the last 130-300 s, the way ahead open)."""
        p = self.p
        move = p.recovery_distance / p.recovery_speed
        turn = 0.5 / (0.5 * p.w_max)
        r = -1.0 if last.w > 0.0 else 1.0
        if last.v == 0.0:
            return [(move, p.recovery_speed, 0.0), (move, -p.recovery_speed, 0.0),
                    (turn, 0.0, r * 0.5 * p.w_max)]
        d = -1.0 if last.v > 0.0 else 1.0
        return [(move, d * p.recovery_speed, 0.0), (turn, 0.0, r * 0.5 * p.w_max),
                (turn, 0.0, -r * 0.5 * p.w_max), (move, -d * p.recovery_speed, 0.0)]

    def _queue(self, moves: list[tuple[float, float, float]], t: float, escape: bool = False) -> None:
        self._recovery = list(moves)
        self._recovery_until = t
        self._escaping = escape
        self._skipped = False

    def _start_recovery(self, points: np.ndarray, t: float) -> Command:
        self.counts["stuck"] += 1
        d = 1.0 if self._front_free(points) else -1.0
        # Turn towards the more open side, judged from the scan.
        side = free_distance(points, np.radians([60.0, -60.0]), self.p, self.p.avoid_margin)
        turn = 1.0 if side[0] >= side[1] else -1.0
        self._queue([
            (self.p.recovery_distance / self.p.recovery_speed, d * self.p.recovery_speed, 0.0),
            (self.p.recovery_turn / (0.5 * self.p.w_max), 0.0, turn * 0.5 * self.p.w_max),
        ], t)
        self._blocked_since = None
        self._give_up("stuck")
        return self._recover(points, t)

    def _refused(self, v: float, points: np.ndarray) -> bool:
        """Whether a recovery move of forward speed ``v`` (m/s; 0: a turn) cannot start: a turn
        that would sweep into a surface seen, or a forward move the safety stop holds (the body's
        own path, no margin)."""
        if v == 0.0:
            return self._turn_blocked()
        return v > 0.0 and safety_limit(points, v, self.p, margin=0.0) <= 0.0

    def _recover(self, points: np.ndarray, t: float) -> Command:
        if t >= self._recovery_until:
            if self._escaping and not self._skipped and self._recovery_cmd != (0.0, 0.0):
                self._recovery = []  # that escape move ran its course: clear
            self._skipped = False
            if not self._recovery:
                self._recovery_cmd = (0.0, 0.0)
                return Command(0.0, 0.0, "recovered")
            duration, v, w = self._recovery.pop(0)
            while self._recovery and self._refused(v, points):
                duration, v, w = self._recovery.pop(0)
            if self._refused(v, points):
                self._recovery_cmd = (0.0, 0.0)
                return Command(0.0, 0.0, "recovered")
            self._recovery_until = t + duration
            self._recovery_cmd = (v, w)
        v, w = self._recovery_cmd
        # Only what the body itself would hit stops a recovery move: a robot pressed against a wall
        # it stands parallel to has that wall within the avoidance margin, and with the margin
        # every move was refused (aliasing seed 2: wedged in a corner for the last 200 s).
        return Command(safety_limit(points, v, self.p, margin=0.0), w, "recovering")
