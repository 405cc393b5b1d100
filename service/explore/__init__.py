"""Autonomous exploration (method.md §8): a planner over the mapper's ASRs and a velocity controller.

**Planner** (:class:`Planner`, pure apart from its memory of what it already tried). Inside the
current ASR it goes to each ``unknown`` region of the boundary in turn (nearest first) until the
enclosure is complete; then it takes the current ASR's *largest unexplored exit* (depth first); when
every exit of the current ASR is explored it *backtracks* along the topological map to the nearest
ASR (fewest metres between centres in the global frame) with an unexplored exit; when the
topological map offers no way there (the way out failed), it heads across the current ASR for the
nearest unexplored exit of any ASR in the global frame (``goto``); when none is left, the exits that
failed are retried (``retries`` rounds, each ending after ``retry_budget`` seconds without new
space); then, once, the unknown regions it only looked at from afar are visited (``visit_round``,
bounded like a retry round); then, once, the straight pieces of linked exits' runs are taken as
exits of their own (``side_openings``: a doorway merged into the way back), bounded the same way;
then it is *done*.
An exit is crossed on its chord's normal, or, when its run of exit edges begins or ends with a wall
seen at a grazing angle (a corridor's end seen from inside: a U of exit edges), through what is
left between those arms (:func:`crossing`).
An exit is explored when it is narrower than ``min_exit_width`` (a slot between furniture, not a
way on), when it leads somewhere (``to`` is set, or a link starts from it; a link naming
an exit the ASR no longer has is travelled through the other side's), when crossing it failed, when
it was seen shut (a surface right behind it in a scan: :meth:`Planner.shut_exits`), when the space
beyond it is already inside other ASRs (``known_depths``, ``known_cover``: in an open-plan room
every gap between tables is an exit into the same room), or, in a duplicate ASR (method.md §5.5),
when the matched ASR has an explored exit at the same place in the global frame: the duplicate's
space is known. An unknown region is a run of consecutive ``unknown`` boundary edges at least
``min_unknown`` long; it is looked at once, from the nearest point of the ASR shrunk by
``clearance``, then remembered (in the ASR's own frame, which never moves) so that regions that stay
unknown (a max-range cut of a long hall, space behind furniture) do not hold exploration up; one
whose space other ASRs already hold (``known_radius``) needs no look. A backtrack link whose
crossing led into an ASR off the route (neither the next hop nor a duplicate of it) fails as an
exit does: taken again it would only flip the robot between the two ASRs. A link whose two exits
lie more than ``LINK_GAP`` apart in the global frame is travelled, both ways, through the narrower
of the two: the wider is an occlusion the mapper took for an entrance, not the doorway crossed.

**Controller** (:class:`Explorer`): turn to the target, then drive, steering to the free heading
nearest the target (or, when the straight line to it leaves the ASR, nearest a point ahead on a
path planned on a grid inside the ASR polygon) from the latest scan; a laser safety stop (no
forward motion while a scan point in the robot's path is closer to the laser than
``stop_distance``); stuck detection (no progress towards the goal for ``stuck_time`` s) and
recovery (back off or creep forward, turn to the most open side, give the goal up and plan
again); an exit whose straight way through the scan shows blocked just beyond it is given up at
once; an exit goal chosen in more than ``max_attempts`` separate attempts (each timed from its first
choice) is given up (the robot goes round a loop, or the mapper flips between two ASRs).

Frames: targets and the robot pose are in the current ASR's frame (m, m, rad); scan points in the
robot frame (x forward, y left); velocities out are ``v`` (m/s, forward) and ``w`` (rad/s,
counter-clockwise), as P2OS VEL/RVEL take them after unit conversion.
"""

from service.explore.crossing import crossing, exit_run, side_openings
from service.explore.explorer import Explorer
from service.explore.links import LINK_GAP, exit_of
from service.explore.params import ExploreParams
from service.explore.paths import plan_path
from service.explore.planner import Planner
from service.explore.regions import exit_normal, unknown_regions, unknown_runs
from service.explore.safety import Command, free_distance, safety_limit, scan_points
from service.explore.view import Goal, LinkRef, MapView, Memory, links_of

__all__ = [
    "LINK_GAP",
    "Command",
    "ExploreParams",
    "Explorer",
    "Goal",
    "LinkRef",
    "MapView",
    "Memory",
    "Planner",
    "crossing",
    "exit_normal",
    "exit_of",
    "exit_run",
    "free_distance",
    "links_of",
    "plan_path",
    "safety_limit",
    "scan_points",
    "side_openings",
    "unknown_regions",
    "unknown_runs",
]
