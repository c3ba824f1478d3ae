"""Compiled kernels of the vectorised highway: highway-env's model, one frame at a time.

Every function mirrors a highway-env 1.12.1 method (named in its docstring) on a straight
road whose lanes run along x, lane k centred at y = LANE_WIDTH * k. State lives in three
arrays per batch, indexed ``[env, vehicle, field]`` with the field constants below; vehicle 0
is the ego, 1..n the background in spawn order (highway-env's ``road.vehicles`` order, which
its sequential updates depend on).

Written by hand with numba because no library simulates this model in batch: EnvPool's C++
port has no per-vehicle behaviour parameters, perception radius or lane-change reward.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from bgap.common import vocab
from bgap.traffic import road

# Float state fields --------------------------------------------------------------------
X, Y, HEADING, SPEED, TARGET_SPEED, TIMER, IMPACT_X, IMPACT_Y, STEER, ACC = range(10)
N_FLOAT = 10
# Integer state fields ------------------------------------------------------------------
LANE, TARGET_LANE, CRASHED, HAS_IMPACT, LABEL, SPEED_INDEX = range(6)
N_INT = 6
# Driver parameters (highway-env IDMVehicle attribute in brackets) -------------------------
P_T, P_D0, P_A, P_B, P_DELTA, P_POLITENESS, P_GAIN, P_BSAFE, P_AMAX, P_VMAX, P_OWN = range(11)
N_PARAM = 11
# P_T [TIME_WANTED], P_D0 [DISTANCE_WANTED, centre to centre], P_A [COMFORT_ACC_MAX],
# P_B [-COMFORT_ACC_MIN], P_DELTA [DELTA], P_POLITENESS, P_GAIN [LANE_CHANGE_MIN_ACC_GAIN],
# P_BSAFE [LANE_CHANGE_MAX_BRAKING_IMPOSED], P_AMAX [ACC_MAX], P_VMAX [MAX_SPEED],
# P_OWN: 1 for bgap's BehaviorVehicle (own parameters in predictions, no speed-limit clip).

# Replay (bgap.traffic.replay): per vehicle [track, state, own v0], states below ------------
R_TRACK, R_STATE, R_OWN_V0 = range(3)
R_SIMULATED, R_SWITCHED, R_PENDING, R_PARKED, R_LOG, R_GONE = range(6)
# (>= R_LOG: following its log; R_GONE: it left this frame and is parked after the frame)
PARK_X, PARK_SPACING = -1.0e7, 50.0  # where absent vehicles wait: off the road, apart

# Labels and ego meta-actions (bgap.traffic.road: highway-env's DiscreteMetaAction.ACTIONS_ALL)
EGO, CONSERVATIVE, AGGRESSIVE = (vocab.LABEL_CODES[k] for k in (vocab.EGO, *vocab.CLASSES))
LANE_LEFT, IDLE, LANE_RIGHT = road.LANE_LEFT, road.IDLE, road.LANE_RIGHT
FASTER, SLOWER = road.FASTER, road.SLOWER

# Constants of highway-env's vehicles and road (bgap.traffic.road reads them from highway-env)
LENGTH, WIDTH = road.VEHICLE_LENGTH, road.VEHICLE_WIDTH
DIAGONAL = math.sqrt(LENGTH**2 + WIDTH**2)
LANE_WIDTH = road.LANE_WIDTH
ROAD_LENGTH = road.ROAD_LENGTH
SPEED_LIMIT = road.SPEED_LIMIT
TAU_ACC, TAU_HEADING, TAU_LATERAL = road.TAU_ACC, road.TAU_HEADING, road.TAU_LATERAL
KP_A, KP_HEADING, KP_LATERAL = 1 / TAU_ACC, 1 / TAU_HEADING, 1 / TAU_LATERAL
MAX_STEERING = road.MAX_STEERING
LANE_CHANGE_DELAY = road.LANE_CHANGE_DELAY
EGO_MAX_SPEED, MIN_SPEED = road.EGO_MAX_SPEED, road.MIN_SPEED

_jit = nb.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def not_zero(x: float) -> float:
    """utils.not_zero (eps 1e-2)."""
    if abs(x) > 1e-2:
        return x
    return 1e-2 if x >= 0 else -1e-2


@_jit
def wrap_to_pi(x: float) -> float:
    return ((x + math.pi) % (2 * math.pi)) - math.pi


@_jit
def closest_lane(y: float, lanes: int) -> int:
    """RoadNetwork.get_closest_lane_index on parallel straight lanes (ties: lower index)."""
    best, best_d = 0, abs(y)
    for k in range(1, lanes):
        d = abs(y - LANE_WIDTH * k)
        if d < best_d:
            best, best_d = k, d
    return best


@_jit
def _on_lane(f, b, v, lane):
    """StraightLane.on_lane with margin 1: |lat| <= width/2 + 1, -LENGTH <= s < len + LENGTH."""
    s_v = f[b, v, X]
    lat = f[b, v, Y] - LANE_WIDTH * lane
    return abs(lat) <= LANE_WIDTH / 2 + 1 and -LENGTH <= s_v < ROAD_LENGTH + LENGTH


@_jit
def sort_by_x(f, b, n, order, rank):
    """Keep ``order`` (vehicle indices) sorted by x; insertion sort, linear on the nearly
    sorted order of the previous frame. ``rank`` is its inverse."""
    for a in range(1, n):
        v = order[a]
        x = f[b, v, X]
        c = a
        while c > 0 and f[b, order[c - 1], X] > x:
            order[c] = order[c - 1]
            c -= 1
        order[c] = v
    for a in range(n):
        rank[order[a]] = a


@_jit
def neighbours(f, b, n, i, lane, order, rank):
    """Road.neighbour_vehicles(vehicle i, lane): (preceding, following), -1 for none.

    highway-env scans every vehicle: the preceding one has the smallest s >= s_i (ties: the
    last in road order), the following one the largest s < s_i (ties: the first). We walk
    outwards from i in x order instead, which finds the same vehicles in a few steps."""
    s = f[b, i, X]
    start = rank[i]
    while start > 0 and f[b, order[start - 1], X] >= s:  # vehicles level with i come first
        start -= 1
    front, s_front = -1, 0.0
    for a in range(start, n):
        v = order[a]
        if v == i or not _on_lane(f, b, v, lane):
            continue
        s_v = f[b, v, X]
        if front >= 0 and s_v > s_front:
            break
        if front < 0 or v > front:
            front, s_front = v, s_v
    rear, s_rear = -1, 0.0
    for a in range(start - 1, -1, -1):
        v = order[a]
        if not _on_lane(f, b, v, lane):
            continue
        s_v = f[b, v, X]
        if rear >= 0 and s_v < s_rear:
            break
        if rear < 0 or v < rear:
            rear, s_rear = v, s_v
    return front, rear


@_jit
def desired_gap(f, p, b, driver, j, front):
    """IDMVehicle.desired_gap with ``driver``'s parameters for vehicle j behind ``front``."""
    hj, hf = f[b, j, HEADING], f[b, front, HEADING]
    vj, vf = f[b, j, SPEED], f[b, front, SPEED]
    if hj == 0.0 and hf == 0.0:  # both along the road: the projection below is exactly this
        dv = vj - vf
    else:
        cj, sj = math.cos(hj), math.sin(hj)
        dv = (vj * cj - vf * math.cos(hf)) * cj + (vj * sj - vf * math.sin(hf)) * sj
    ab = p[b, driver, P_A] * p[b, driver, P_B]
    return p[b, driver, P_D0] + vj * p[b, driver, P_T] + vj * dv / (2 * math.sqrt(ab))


@_jit
def acceleration(f, g, p, b, decider, j, front):
    """IDM acceleration of vehicle j behind ``front`` as vehicle ``decider`` predicts it.

    highway-env's IDMVehicle uses the decider's parameters for everyone and clips every
    desired speed to the speed limit; bgap's BehaviorVehicle (P_OWN) uses j's own parameters
    when j is a background driver and clips only vehicles that are not BehaviorVehicles.
    """
    if j < 0:
        return 0.0
    own_i = p[b, decider, P_OWN] > 0
    own_j = p[b, j, P_OWN] > 0
    driver = j if (own_i and g[b, j, LABEL] != EGO) else decider
    target = f[b, j, TARGET_SPEED]
    if not (own_i and own_j):
        target = min(max(target, 0.0), SPEED_LIMIT)
    a = p[b, driver, P_A]
    ratio = max(f[b, j, SPEED], 0.0) / abs(not_zero(target))
    acc = a * (1 - ratio ** p[b, driver, P_DELTA])
    if front >= 0:
        d = f[b, front, X] - f[b, j, X]
        gap = desired_gap(f, p, b, driver, j, front)
        acc -= a * (gap / not_zero(d)) ** 2
    return acc


@_jit
def steering_control(f, b, i, target_lane):
    """ControlledVehicle.steering_control towards the centre of ``target_lane``."""
    speed = f[b, i, SPEED]
    lateral = f[b, i, Y] - LANE_WIDTH * target_lane
    if lateral == 0.0 and f[b, i, HEADING] == 0.0 and speed > 0:
        return 0.0  # on the lane's centre line, heading along it: every term below is 0
    lateral_speed_command = -KP_LATERAL * lateral
    heading_command = math.asin(min(max(lateral_speed_command / not_zero(speed), -1.0), 1.0))
    heading_ref = min(max(heading_command, -math.pi / 4), math.pi / 4)
    heading_rate = KP_HEADING * wrap_to_pi(heading_ref - f[b, i, HEADING])
    slip = math.asin(min(max(LENGTH / 2 / not_zero(speed) * heading_rate, -1.0), 1.0))
    steer = math.atan(2 * math.tan(slip))
    return min(max(steer, -MAX_STEERING), MAX_STEERING)


@_jit
def reachable(f, b, i, lane, lanes):
    """AbstractLane.is_reachable_from for lane ``lane`` (which must exist)."""
    if lane < 0 or lane >= lanes:
        return False
    lat = f[b, i, Y] - LANE_WIDTH * lane
    return abs(lat) <= 2 * LANE_WIDTH and 0 <= f[b, i, X] < ROAD_LENGTH + LENGTH


@_jit
def mobil(f, g, p, b, n, i, lane, order, rank):
    """IDMVehicle.mobil: should vehicle i move to ``lane``?"""
    new_pre, new_fol = neighbours(f, b, n, i, lane, order, rank)
    new_fol_a = acceleration(f, g, p, b, i, new_fol, new_pre)
    new_fol_pred_a = acceleration(f, g, p, b, i, new_fol, i)
    if new_fol_pred_a < -p[b, i, P_BSAFE]:
        return False
    old_pre, old_fol = neighbours(f, b, n, i, g[b, i, LANE], order, rank)
    self_pred_a = acceleration(f, g, p, b, i, i, new_pre)
    self_a = acceleration(f, g, p, b, i, i, old_pre)
    old_fol_a = acceleration(f, g, p, b, i, old_fol, i)
    old_fol_pred_a = acceleration(f, g, p, b, i, old_fol, old_pre)
    jerk = (
        self_pred_a
        - self_a
        + p[b, i, P_POLITENESS] * (new_fol_pred_a - new_fol_a + old_fol_pred_a - old_fol_a)
    )
    return not (jerk < p[b, i, P_GAIN])


@_jit
def change_lane_policy(f, g, p, b, n, i, lanes, order, rank):
    """IDMVehicle.change_lane_policy (abort a change if someone else targets the same lane;
    otherwise, every LANE_CHANGE_DELAY, try both side lanes with MOBIL, right one last)."""
    lane, target = g[b, i, LANE], g[b, i, TARGET_LANE]
    if lane != target:
        for v in range(n):
            if v != i and g[b, v, LANE] != target and g[b, v, TARGET_LANE] == target:
                d = f[b, v, X] - f[b, i, X]
                if 0 < d < desired_gap(f, p, b, i, i, v):
                    g[b, i, TARGET_LANE] = lane
                    break
        return
    if not LANE_CHANGE_DELAY < f[b, i, TIMER]:
        return
    f[b, i, TIMER] = 0.0
    for candidate in (lane - 1, lane + 1):
        if not reachable(f, b, i, candidate, lanes):  # also: the lane exists
            continue
        if abs(f[b, i, SPEED]) < 1:
            continue
        if mobil(f, g, p, b, n, i, candidate, order, rank):
            g[b, i, TARGET_LANE] = candidate


@_jit
def idm_act(f, g, p, b, n, i, lanes, order, rank):
    """IDMVehicle.act: lane-change decision, steering, IDM acceleration (min over both lanes
    while changing), clipped to ACC_MAX. A crashed vehicle keeps its action."""
    if g[b, i, CRASHED]:
        return
    change_lane_policy(f, g, p, b, n, i, lanes, order, rank)
    f[b, i, STEER] = steering_control(f, b, i, g[b, i, TARGET_LANE])
    front, _ = neighbours(f, b, n, i, g[b, i, LANE], order, rank)
    acc = acceleration(f, g, p, b, i, i, front)
    if g[b, i, LANE] != g[b, i, TARGET_LANE]:
        front, _ = neighbours(f, b, n, i, g[b, i, TARGET_LANE], order, rank)
        acc = min(acc, acceleration(f, g, p, b, i, i, front))
    amax = p[b, i, P_AMAX]
    f[b, i, ACC] = min(max(acc, -amax), amax)


@_jit
def speed_to_index(speed, speeds):
    """MDPVehicle.speed_to_index (np.round: halves to even)."""
    m = speeds.shape[0]
    if m == 1:
        return 0
    x = (speed - speeds[0]) / (speeds[m - 1] - speeds[0])
    return int(min(max(np.round(x * (m - 1)), 0), m - 1))


@_jit
def ego_act(f, g, b, action, speeds, lanes):
    """MDPVehicle.act(action): update the target speed or lane, then the two controllers.

    ``action`` < 0 is ``act()`` without a meta-action (what Road.act does every frame)."""
    if action == FASTER or action == SLOWER:
        idx = speed_to_index(f[b, 0, SPEED], speeds) + (1 if action == FASTER else -1)
        idx = min(max(idx, 0), speeds.shape[0] - 1)
        g[b, 0, SPEED_INDEX] = idx
        f[b, 0, TARGET_SPEED] = speeds[idx]
    elif action == LANE_LEFT or action == LANE_RIGHT:
        cand = g[b, 0, TARGET_LANE] + (-1 if action == LANE_LEFT else 1)
        cand = min(max(cand, 0), lanes - 1)
        if reachable(f, b, 0, cand, lanes):
            g[b, 0, TARGET_LANE] = cand
    f[b, 0, STEER] = steering_control(f, b, 0, g[b, 0, TARGET_LANE])
    f[b, 0, ACC] = KP_A * (f[b, 0, TARGET_SPEED] - f[b, 0, SPEED])


@_jit
def vehicle_step(f, g, p, b, i, dt, lanes):
    """Vehicle.step with clip_actions (crashed: brake to a stop; speed capped at MAX_SPEED)."""
    if g[b, i, LABEL] != EGO:
        f[b, i, TIMER] += dt
    if g[b, i, CRASHED]:
        f[b, i, STEER] = 0.0
        f[b, i, ACC] = -1.0 * f[b, i, SPEED]
    speed = f[b, i, SPEED]
    vmax = p[b, i, P_VMAX]
    if speed > vmax:
        f[b, i, ACC] = min(f[b, i, ACC], 1.0 * (vmax - speed))
    elif speed < MIN_SPEED:
        f[b, i, ACC] = max(f[b, i, ACC], 1.0 * (MIN_SPEED - speed))
    h = f[b, i, HEADING]
    if f[b, i, STEER] == 0.0 and h == 0.0:  # straight along x: the same numbers, no trigonometry
        beta = f[b, i, STEER]  # atan(0.5 * tan(+-0)) is that same signed zero
        f[b, i, X] += speed * dt
    else:
        beta = math.atan(0.5 * math.tan(f[b, i, STEER]))
        f[b, i, X] += speed * math.cos(h + beta) * dt
        f[b, i, Y] += speed * math.sin(h + beta) * dt
    if g[b, i, HAS_IMPACT]:
        f[b, i, X] += f[b, i, IMPACT_X]
        f[b, i, Y] += f[b, i, IMPACT_Y]
        g[b, i, CRASHED] = 1
        g[b, i, HAS_IMPACT] = 0
    f[b, i, HEADING] = h + speed * math.sin(beta) / (LENGTH / 2) * dt
    f[b, i, SPEED] = speed + f[b, i, ACC] * dt
    g[b, i, LANE] = closest_lane(f[b, i, Y], lanes)


@_jit
def _corners(x, y, h, out):
    """RoadObject.polygon: 4 corners (the closing point only repeats the first)."""
    c, s = math.cos(h), math.sin(h)
    for k in range(4):
        lx = -LENGTH / 2 if k < 2 else LENGTH / 2
        ly = -WIDTH / 2 if (k == 0 or k == 3) else WIDTH / 2
        out[k, 0] = x + c * lx - s * ly
        out[k, 1] = y + s * lx + c * ly


@_jit
def _interval_distance(min_a, max_a, min_b, max_b):
    return min_b - max_a if min_a < min_b else min_a - max_b


@_jit
def polygons_intersecting(pa, pb, da_x, da_y, db_x, db_y, ca_x, ca_y, cb_x, cb_y):
    """utils.are_polygons_intersecting (separating axes, with displacement):
    (intersecting, will_intersect, translation x, translation y)."""
    intersecting, will = True, True
    min_distance = np.inf
    ax_x, ax_y = 0.0, 0.0
    done = False
    for which in range(2):
        poly = pa if which == 0 else pb
        for e in range(4):
            p1x, p1y = poly[e, 0], poly[e, 1]
            p2x, p2y = poly[(e + 1) % 4, 0], poly[(e + 1) % 4, 1]
            nx, ny = -p2y + p1y, p2x - p1x
            norm = math.sqrt(nx * nx + ny * ny)
            nx, ny = nx / norm, ny / norm
            min_a, max_a, min_b, max_b = np.inf, -np.inf, np.inf, -np.inf
            for k in range(4):
                qa = pa[k, 0] * nx + pa[k, 1] * ny
                qb = pb[k, 0] * nx + pb[k, 1] * ny
                min_a, max_a = min(min_a, qa), max(max_a, qa)
                min_b, max_b = min(min_b, qb), max(max_b, qb)
            if _interval_distance(min_a, max_a, min_b, max_b) > 0:
                intersecting = False
            vp = nx * (da_x - db_x) + ny * (da_y - db_y)
            if vp < 0:
                min_a += vp
            else:
                max_a += vp
            distance = _interval_distance(min_a, max_a, min_b, max_b)
            if distance > 0:
                will = False
            if not intersecting and not will:
                done = True
                break
            if abs(distance) < min_distance:
                min_distance = abs(distance)
                dx, dy = ca_x - cb_x, ca_y - cb_y
                if dx * nx + dy * ny > 0:
                    ax_x, ax_y = nx, ny
                else:
                    ax_x, ax_y = -nx, -ny
        if done:
            break
    if will:
        return intersecting, will, min_distance * ax_x, min_distance * ax_y
    return intersecting, will, 0.0, 0.0


@_jit
def handle_collisions(f, g, b, i, j, dt, pa, pb):
    """RoadObject.handle_collisions(i, j): push apart when they will intersect, crash both
    when they intersect."""
    dx, dy = f[b, j, X] - f[b, i, X], f[b, j, Y] - f[b, i, Y]
    reach = DIAGONAL + f[b, i, SPEED] * dt
    if dx * dx + dy * dy > reach * reach:  # the spherical pre-check, squared
        return
    hi, hj = f[b, i, HEADING], f[b, j, HEADING]
    _corners(f[b, i, X], f[b, i, Y], hi, pa)
    _corners(f[b, j, X], f[b, j, Y], hj, pb)
    vi, vj = f[b, i, SPEED] * dt, f[b, j, SPEED] * dt
    inter, will, tx, ty = polygons_intersecting(
        pa,
        pb,
        vi * math.cos(hi),
        vi * math.sin(hi),
        vj * math.cos(hj),
        vj * math.sin(hj),
        f[b, i, X],
        f[b, i, Y],
        f[b, j, X],
        f[b, j, Y],
    )
    if will:
        f[b, i, IMPACT_X], f[b, i, IMPACT_Y] = tx / 2, ty / 2
        f[b, j, IMPACT_X], f[b, j, IMPACT_Y] = -tx / 2, -ty / 2
        g[b, i, HAS_IMPACT] = 1
        g[b, j, HAS_IMPACT] = 1
    if inter:
        g[b, i, CRASHED] = 1
        g[b, j, CRASHED] = 1


@_jit
def collisions(f, g, b, n, dt, order, pairs, pa, pb, rp=None):
    """Road.step's pairwise handle_collisions, for the pairs that can touch.

    highway-env tests all pairs (i < j) in order; a pair can only touch when its centres
    are within DIAGONAL + speed * dt, so we sweep along x for candidates, then handle them
    in highway-env's order (an impact set by a later pair overwrites an earlier one).
    ``rp``: a replay's vehicle states (:func:`replay_frame`): two vehicles following their
    logs are not checked."""
    vmax = 0.0
    for v in range(n):
        vmax = max(vmax, abs(f[b, v, SPEED]))
    reach = DIAGONAL + vmax * dt
    m = 0
    for a in range(n):
        i = order[a]
        for c in range(a + 1, n):
            j = order[c]
            if f[b, j, X] - f[b, i, X] > reach:
                break
            key = min(i, j) * n + max(i, j)
            pos = m  # insertion into the sorted list of pair keys
            while pos > 0 and pairs[pos - 1] > key:
                pairs[pos] = pairs[pos - 1]
                pos -= 1
            pairs[pos] = key
            m += 1
    for k in range(m):
        i, j = pairs[k] // n, pairs[k] % n
        if rp is not None and rp[b, i, R_STATE] >= R_LOG and rp[b, j, R_STATE] >= R_LOG:
            continue
        handle_collisions(f, g, b, i, j, dt, pa, pb)


@_jit
def frame(f, g, p, b, n, dt, lanes, order, rank, pairs, pa, pb):
    """One simulation frame of env b: Road.act (ego first, then background in order), then
    Road.step (every vehicle, then every pair's collisions)."""
    sort_by_x(f, b, n, order, rank)
    for i in range(n):
        if g[b, i, LABEL] == EGO:  # ControlledVehicle.act() without a meta-action
            f[b, i, STEER] = steering_control(f, b, i, g[b, i, TARGET_LANE])
            f[b, i, ACC] = KP_A * (f[b, i, TARGET_SPEED] - f[b, i, SPEED])
        else:
            idm_act(f, g, p, b, n, i, lanes, order, rank)
    for i in range(n):
        vehicle_step(f, g, p, b, i, dt, lanes)
    sort_by_x(f, b, n, order, rank)
    collisions(f, g, b, n, dt, order, pairs, pa, pb)


@_jit
def idm_follow(f, g, p, b, n, i, order, rank):
    """IDMVehicle.act with lane changes disabled (a replayed vehicle that switched to IDM):
    steering to its target lane and the IDM acceleration, as :func:`idm_act`. (Its lines
    repeat :func:`idm_act`'s on purpose: idm_act calling this instead made the simulated
    step 5-10% slower, dense 6,843 vs 7,582 env-steps/s, medians of 3.)"""
    f[b, i, STEER] = steering_control(f, b, i, g[b, i, TARGET_LANE])
    front, _ = neighbours(f, b, n, i, g[b, i, LANE], order, rank)
    acc = acceleration(f, g, p, b, i, i, front)
    if g[b, i, LANE] != g[b, i, TARGET_LANE]:
        front, _ = neighbours(f, b, n, i, g[b, i, TARGET_LANE], order, rank)
        acc = min(acc, acceleration(f, g, p, b, i, i, front))
    amax = p[b, i, P_AMAX]
    f[b, i, ACC] = min(max(acc, -amax), amax)


@_jit
def _replayed_state(f, g, b, i, tracks, k, lanes):
    """Vehicle i at sample ``k`` of the replay's tracks (x, y, vx, vy):
    bgap.envs.replay.ReplayVehicle.step."""
    x, y, vx, vy = tracks[k, 0], tracks[k, 1], tracks[k, 2], tracks[k, 3]
    f[b, i, X], f[b, i, Y] = x, y
    f[b, i, HEADING], f[b, i, SPEED] = math.atan2(vy, vx), math.hypot(vx, vy)
    g[b, i, HAS_IMPACT] = 0  # the log does not yield
    g[b, i, LANE] = closest_lane(y, lanes)


@_jit
def _park(f, b, i):
    f[b, i, X], f[b, i, Y], f[b, i, SPEED], f[b, i, HEADING] = (
        PARK_X - PARK_SPACING * i,
        0.0,
        0.0,
        0.0,
    )


@_jit
def replay_frame(
    f,
    g,
    p,
    b,
    n,
    dt,
    lanes,
    order,
    rank,
    pairs,
    pa,
    pb,
    rp,
    rframe,
    tracks,
    start,
    first,
    length,
    reactive,
):
    """One simulation frame of env b replaying a recording (bgap.envs.replay, the
    reference): Road.act (the ego; each replayed vehicle switches to IDM in reactive mode
    when its leader is the ego or a switched vehicle closer than its desired gap), Road.step
    (the ego and switched vehicles move, the others take their next recorded sample or
    leave), collisions (not between two logs), then the frame's exits and entries.
    ``rp[b, i]``: (track, state, own v0); track t's samples are ``tracks[start[t]:start[t] +
    length[t]]``, from scene frame ``first[t]``; ``rframe[b]``: the env's scene frame."""
    sort_by_x(f, b, n, order, rank)
    for i in range(n):
        state = rp[b, i, R_STATE]
        if g[b, i, LABEL] == EGO:
            f[b, i, STEER] = steering_control(f, b, i, g[b, i, TARGET_LANE])
            f[b, i, ACC] = KP_A * (f[b, i, TARGET_SPEED] - f[b, i, SPEED])
            continue
        if state == R_LOG and reactive:
            front, _ = neighbours(f, b, n, i, g[b, i, LANE], order, rank)
            if front >= 0 and (g[b, front, LABEL] == EGO or rp[b, front, R_STATE] == R_SWITCHED):
                if f[b, front, X] - f[b, i, X] < desired_gap(f, p, b, i, i, front):
                    rp[b, i, R_STATE] = state = R_SWITCHED
                    g[b, i, TARGET_LANE] = g[b, i, LANE]
                    if rp[b, i, R_OWN_V0] == 0:
                        f[b, i, TARGET_SPEED] = f[b, i, SPEED]
        if state == R_SWITCHED and not g[b, i, CRASHED]:
            idm_follow(f, g, p, b, n, i, order, rank)
    for i in range(n):
        state = rp[b, i, R_STATE]
        if g[b, i, LABEL] == EGO or state == R_SWITCHED:
            vehicle_step(f, g, p, b, i, dt, lanes)
        elif state == R_LOG:
            t = rp[b, i, R_TRACK]
            k = rframe[b] + 1 - first[t]
            if k >= length[t]:
                rp[b, i, R_STATE] = R_GONE  # stays for this frame's collisions
            else:
                _replayed_state(f, g, b, i, tracks, start[t] + k, lanes)
    sort_by_x(f, b, n, order, rank)
    collisions(f, g, b, n, dt, order, pairs, pa, pb, rp)
    rframe[b] += 1
    for i in range(n):  # ReplayScene.after_frame: exits, then entries in road order
        state = rp[b, i, R_STATE]
        if state == R_GONE:
            rp[b, i, R_STATE] = R_PARKED
            _park(f, b, i)
        elif state == R_PENDING and first[rp[b, i, R_TRACK]] == rframe[b]:
            t = rp[b, i, R_TRACK]
            rp[b, i, R_STATE] = R_LOG
            _replayed_state(f, g, b, i, tracks, start[t], lanes)
            if rp[b, i, R_OWN_V0] == 0:
                f[b, i, TARGET_SPEED] = f[b, i, SPEED]
            g[b, i, TARGET_LANE] = g[b, i, LANE]


@nb.njit(cache=True, parallel=True, nogil=True, error_model="numpy")
def replay_batch(
    f, g, p, actions, speeds, frames, dt, lanes, rp, rframe, tracks, start, first, length, reactive
):
    """:func:`step_batch` for replayed traffic (:func:`replay_frame`)."""
    n_env, n = f.shape[0], f.shape[1]
    for b in nb.prange(n_env):
        if actions[b] < 0:  # FINISHED: the caller no longer counts this env's episode
            continue
        pa = np.empty((4, 2))
        pb = np.empty((4, 2))
        order = np.arange(n)
        rank = np.arange(n)
        pairs = np.empty(n * (n - 1) // 2, np.int64)
        for k in range(frames):
            if k == 0:
                ego_act(f, g, b, actions[b], speeds, lanes)
            replay_frame(
                f,
                g,
                p,
                b,
                n,
                dt,
                lanes,
                order,
                rank,
                pairs,
                pa,
                pb,
                rp,
                rframe,
                tracks,
                start,
                first,
                length,
                reactive,
            )


# Random draws: numpy's Generator algorithms on a PCG64 stream reached through its ctypes
# interface (``next_double``, ``next_uint32`` and the state's address, passed as arguments
# so that the compiled code stays cacheable). Written out because numba's own Generator
# support costs ~30 us to unbox per call, more than the whole scene draw; these give numpy's
# numbers from numpy's streams (tests/test_sim.py replays the draws with numpy).


@_jit
def _uniform(next_double, state, low, high):
    """Generator.uniform(low, high): low + (high - low) * next_double (random_uniform)."""
    return low + (high - low) * next_double(state)


@_jit
def _integer(next_uint32, state, high):
    """Generator.integers(0, high) for 1 <= high <= 2**32 - 1 (bounded_lemire_uint32)."""
    rng = np.uint64(high - 1)
    if rng == 0:
        return 0
    rng_excl = rng + np.uint64(1)
    m = np.uint64(next_uint32(state)) * rng_excl
    leftover = m & np.uint64(0xFFFFFFFF)
    if leftover < rng_excl:
        threshold = (np.uint64(0xFFFFFFFF) - rng) % rng_excl
        while leftover < threshold:
            m = np.uint64(next_uint32(state)) * rng_excl
            leftover = m & np.uint64(0xFFFFFFFF)
    return np.int64(m >> np.uint64(32))


@_jit
def _interval(next_uint32, state, top):
    """random_interval(top): a draw in [0, top] by masked rejection (what shuffle uses)."""
    if top == 0:
        return 0
    mask = np.uint64(top)
    for shift in (1, 2, 4, 8, 16, 32):
        mask |= mask >> np.uint64(shift)
    value = np.uint64(next_uint32(state)) & mask
    while value > np.uint64(top):
        value = np.uint64(next_uint32(state)) & mask
    return np.int64(value)


@_jit
def spawn(f, g, p, b, k, ego_lane, setup, speeds, classes, next_double, next_uint32, state):
    """HighwayEnv._create_vehicles with bgap's classes, for env b, drawn from the PCG64
    stream at ``state`` in the order and by the algorithms of numpy's Generator (the numpy
    version of this draw is ``tests/test_sim.py``'s reference): the ego's lane (when
    ``ego_lane`` < 0), its spacing, the permutation of the class labels, the background's
    lanes, speeds and spacings, the IDM deltas, then each class's desired-speed spread.

    Args: ``k`` aggressive drivers among the background; ``setup`` = (lanes, ego_spacing *
    37 m * Vehicle.create_random's spacing factor, 1 / vehicles_density, the spacing
    factor); ``classes`` (3, 3 + N_PARAM): the ego's row, then per class (conservative,
    aggressive) its code, desired speed v0 (NaN: the spawn speed), v0's relative spread
    and its parameter row, whose P_DELTA is NaN where the class draws its delta.
    """
    lanes, ego_offset, inv_density, spread = int(setup[0]), setup[1], setup[2], setup[3]
    n_veh = f.shape[1]
    n = n_veh - 1
    for i in range(n_veh):
        for c in range(f.shape[2]):
            f[b, i, c] = 0.0
        for c in range(g.shape[2]):
            g[b, i, c] = 0
    if ego_lane < 0:
        ego_lane = _integer(next_uint32, state, lanes)
    x = 3 * ego_offset + ego_offset * _uniform(next_double, state, 0.9, 1.1)
    f[b, 0, X], f[b, 0, Y], f[b, 0, SPEED] = x, LANE_WIDTH * ego_lane, 25.0
    g[b, 0, LANE] = ego_lane
    g[b, 0, TARGET_LANE] = ego_lane
    idx = speed_to_index(25.0, speeds)
    g[b, 0, SPEED_INDEX], f[b, 0, TARGET_SPEED] = idx, speeds[idx]
    g[b, 0, LABEL] = EGO
    for q in range(p.shape[2]):
        p[b, 0, q] = classes[0, 3 + q]
    labels = np.empty(n, np.int64)
    for i in range(n):
        labels[i] = AGGRESSIVE if i < k else CONSERVATIVE
    for i in range(n - 1, 0, -1):  # Generator.permutation: shuffle a copy
        j = _interval(next_uint32, state, i)
        labels[i], labels[j] = labels[j], labels[i]
    lanes_bg = np.empty(n, np.int64)
    for i in range(n):
        lanes_bg[i] = _integer(next_uint32, state, lanes)
    v, spacing, deltas = np.empty(n), np.empty(n), np.empty(n)
    for i in range(n):
        v[i] = _uniform(next_double, state, 0.7 * SPEED_LIMIT, 0.8 * SPEED_LIMIT)
    for i in range(n):
        spacing[i] = _uniform(next_double, state, 0.9, 1.1)
    for i in range(n):
        deltas[i] = _uniform(next_double, state, 3.5, 4.5)
    travelled = 0.0  # np.cumsum's running sum, in its order
    for i in range(n):
        travelled += inv_density * (12 + v[i]) * spread * spacing[i]
        j = i + 1
        f[b, j, X] = x + travelled
        f[b, j, Y] = LANE_WIDTH * lanes_bg[i]
        f[b, j, SPEED] = v[i]
        f[b, j, TARGET_SPEED] = v[i]
        f[b, j, TIMER] = ((f[b, j, X] + LANE_WIDTH * lanes_bg[i]) * np.pi) % LANE_CHANGE_DELAY
        g[b, j, LANE] = lanes_bg[i]
        g[b, j, TARGET_LANE] = lanes_bg[i]
        g[b, j, LABEL] = labels[i]
    for c in range(1, classes.shape[0]):
        code = classes[c, 0]
        count = 0
        for i in range(n):
            if labels[i] == code:
                count += 1
                for q in range(p.shape[2]):
                    p[b, i + 1, q] = classes[c, 3 + q]
                if math.isnan(classes[c, 3 + P_DELTA]):
                    p[b, i + 1, P_DELTA] = deltas[i]
        if count == 0 or math.isnan(classes[c, 1]):
            continue
        s = classes[c, 2]
        for i in range(n):  # one draw per vehicle of the class, in road order
            if labels[i] == code:
                f[b, i + 1, TARGET_SPEED] = classes[c, 1] * _uniform(
                    next_double, state, 1 - s, 1 + s
                )


@nb.njit(cache=True, parallel=True, nogil=True, error_model="numpy")
def spawn_batch(
    f, g, p, envs, ks, ego_lane, setup, speeds, classes, next_double, next_uint32, states
):
    """:func:`spawn` for each env in ``envs`` (``ks`` and ``states`` aligned with it), in
    parallel: every env draws from its own stream."""
    for a in nb.prange(envs.shape[0]):
        spawn(
            f,
            g,
            p,
            envs[a],
            ks[a],
            ego_lane,
            setup,
            speeds,
            classes,
            next_double,
            next_uint32,
            states[a],
        )


@_jit
def record(f, g, b, n, out, t):
    """Copy env b's vehicles into out[b, t]: x, y, vx, vy, speed, lane, crashed."""
    for i in range(n):
        h, v = f[b, i, HEADING], f[b, i, SPEED]
        out[b, t, i, 0] = f[b, i, X]
        out[b, t, i, 1] = f[b, i, Y]
        out[b, t, i, 2] = v * math.cos(h)
        out[b, t, i, 3] = v * math.sin(h)
        out[b, t, i, 4] = v
        out[b, t, i, 5] = g[b, i, LANE]
        out[b, t, i, 6] = g[b, i, CRASHED]


@nb.njit(cache=True, parallel=True, nogil=True, error_model="numpy")
def step_batch(f, g, p, actions, speeds, frames, dt, lanes, rec):
    """Advance every env by one policy step: the ego's meta-action on the first frame
    (AbstractEnv._simulate), then ``frames`` simulation frames; an env whose action is
    negative (``FINISHED``) is left as it is. When ``rec`` has one slot per
    frame (shape[1] == frames) every frame's state is written into it."""
    n_env, n = f.shape[0], f.shape[1]
    recording = rec.shape[1] == frames and rec.shape[0] == n_env
    for b in nb.prange(n_env):
        if actions[b] < 0:  # FINISHED: the caller no longer counts this env's episode
            continue
        pa = np.empty((4, 2))
        pb = np.empty((4, 2))
        order = np.arange(n)
        rank = np.arange(n)
        pairs = np.empty(n * (n - 1) // 2, np.int64)
        for k in range(frames):
            if k == 0:
                ego_act(f, g, b, actions[b], speeds, lanes)
            frame(f, g, p, b, n, dt, lanes, order, rank, pairs, pa, pb)
            if recording:
                record(f, g, b, n, rec, k)


@nb.njit(cache=True, parallel=True, nogil=True, error_model="numpy")
def observe_batch(f, g, radius, lanes, x_range, v_range, out, counts):
    """KinematicObservation (presence, x, y, vx, vy; sorted; see_behind; normalised, clipped)
    of every env into out[b] (V rows); counts[b] = (vehicles within the radius, aggressive
    ones among them)."""
    n_env, n = f.shape[0], f.shape[1]
    rows = out.shape[1]
    y_range = LANE_WIDTH * lanes
    for b in nb.prange(n_env):
        for r in range(rows):
            for c in range(5):
                out[b, r, c] = 0.0
        x0, y0, h0, v0 = f[b, 0, X], f[b, 0, Y], f[b, 0, HEADING], f[b, 0, SPEED]
        vx0, vy0 = v0 * math.cos(h0), v0 * math.sin(h0)
        out[b, 0, 0] = 1.0
        out[b, 0, 1] = min(max(x0 / x_range, -1.0), 1.0)
        out[b, 0, 2] = min(max(y0 / y_range, -1.0), 1.0)
        out[b, 0, 3] = min(max(vx0 / v_range, -1.0), 1.0)
        out[b, 0, 4] = min(max(vy0 / v_range, -1.0), 1.0)
        # Vehicles within the radius, stably sorted by |longitudinal distance| (insertion sort:
        # n is small and it keeps highway-env's order among ties).
        idx = np.empty(n, np.int64)
        key = np.empty(n)
        m = 0
        n_aggressive = 0
        for v in range(1, n):
            dx, dy = f[b, v, X] - x0, f[b, v, Y] - y0
            if math.sqrt(dx * dx + dy * dy) < radius:
                if g[b, v, LABEL] == AGGRESSIVE:
                    n_aggressive += 1
                k = abs(dx)
                pos = m
                while pos > 0 and key[pos - 1] > k:
                    key[pos] = key[pos - 1]
                    idx[pos] = idx[pos - 1]
                    pos -= 1
                key[pos] = k
                idx[pos] = v
                m += 1
        counts[b, 0] = m
        counts[b, 1] = n_aggressive
        for r in range(min(m, rows - 1)):
            v = idx[r]
            h, s = f[b, v, HEADING], f[b, v, SPEED]
            out[b, r + 1, 0] = 1.0
            out[b, r + 1, 1] = min(max((f[b, v, X] - x0) / x_range, -1.0), 1.0)
            out[b, r + 1, 2] = min(max((f[b, v, Y] - y0) / y_range, -1.0), 1.0)
            out[b, r + 1, 3] = min(max((s * math.cos(h) - vx0) / v_range, -1.0), 1.0)
            out[b, r + 1, 4] = min(max((s * math.sin(h) - vy0) / v_range, -1.0), 1.0)


@nb.njit(cache=True, nogil=True)
def ego_terms(f, g, before, lanes, speed_lo, speed_hi, out):
    """HighwayEnv._rewards of every env's ego, plus bgap's lane-change term, into out[b]:
    collision, lane change, right lane, high speed, on road, speed, crashed, lane."""
    for b in range(f.shape[0]):
        h, v = f[b, 0, HEADING], f[b, 0, SPEED]
        forward = v * math.cos(h)
        lateral = f[b, 0, Y] - LANE_WIDTH * g[b, 0, LANE]
        out[b, 0] = float(g[b, 0, CRASHED])
        out[b, 1] = 1.0 if g[b, 0, TARGET_LANE] != before[b] else 0.0
        out[b, 2] = g[b, 0, TARGET_LANE] / max(lanes - 1, 1)
        out[b, 3] = min(max((forward - speed_lo) / (speed_hi - speed_lo), 0.0), 1.0)
        on_x = -LENGTH <= f[b, 0, X] < ROAD_LENGTH + LENGTH
        out[b, 4] = 1.0 if (abs(lateral) <= LANE_WIDTH / 2 and on_x) else 0.0
