"""Bezier candidates on hand-made maps (straight road, left turn, arc)."""
import math

import numpy as np
import pytest

from lmpc_mpc import synthetic as S
from lmpc_mpc.reference import (
    Candidate,
    _Polyline,
    bezier_points,
    candidates_for_pose,
    closest_heading,
    route_candidate,
    time_parameterize,
)


def _max_dev(cand: Candidate, centre: np.ndarray) -> float:
    line = _Polyline.of(centre)
    return max(line.project(float(p[0]), float(p[1]))[1] for p in cand.sample(200))


def test_bezier_endpoints_and_degree_one_is_a_line() -> None:
    cps = [(0.0, 0.0), (3.0, 4.0), (10.0, 0.0)]
    pts = bezier_points(cps, 11)
    assert np.allclose(pts[0], cps[0]) and np.allclose(pts[-1], cps[-1])
    line = bezier_points([(0.0, 0.0), (10.0, 0.0)], 11)
    assert np.allclose(line[:, 0], np.linspace(0, 10, 11))


def test_straight_road_keep_and_change_lane() -> None:
    m = S.straight_road()
    cands = candidates_for_pose(m, x_m=20.0, y_m=-4.8, yaw_rad=0.0, lane_id="E0_0")
    labels = [c.label for c in cands]
    assert labels[0] == "continue in lane" and "change to the left lane" in labels
    keep = cands[0]
    assert keep.control_points[0] == (20.0, -4.8)
    assert keep.control_points[-1][0] == pytest.approx(80.0, abs=0.5)
    assert all(abs(p[1] + 4.8) < 1e-6 for p in keep.control_points)
    change = cands[labels.index("change to the left lane")]
    assert change.control_points[-1][1] == pytest.approx(-1.6, abs=1e-6)
    assert keep.length_m() == pytest.approx(60.0, abs=0.5)


def test_left_turn_candidates_through_internal_lanes() -> None:
    m = S.four_way_junction()
    cands = candidates_for_pose(m, x_m=1.6, y_m=-30.0, yaw_rad=math.pi / 2, lane_id="S_in_0")
    by_label = {c.label: c for c in cands}
    assert set(by_label) == {"go straight through the junction", "turn left at the junction",
                             "turn right at the junction"}
    left = by_label["turn left at the junction"]
    assert ":J_1_0" in left.lane_ids and left.lane_ids[-1] == "W_out_0"
    lanes = {ln.id: ln for ln in m.lanes}
    centre = np.vstack([np.asarray(lanes[i].centerline) for i in left.lane_ids])
    assert _max_dev(left, centre) < 1.0  # stays within the lane (width 3.2 m)
    end = np.asarray(left.control_points[-1])
    assert end[0] < -20.0 and end[1] == pytest.approx(1.6, abs=0.1)


def test_arc_candidate_follows_the_arc() -> None:
    m = S.arc_road(radius_m=30.0)
    (cand,) = candidates_for_pose(m, x_m=0.0, y_m=0.0, yaw_rad=0.0, lane_id=None)
    assert cand.lane_ids[0] == "A_0"
    radii = np.hypot(*(cand.sample(100) - [0.0, 30.0]).T)
    assert np.all(np.abs(radii - 30.0) < 1.5)  # within the half lane width (1.6 m)


def test_closest_heading_and_route() -> None:
    m = S.four_way_junction()
    cands = candidates_for_pose(m, x_m=1.6, y_m=-30.0, yaw_rad=math.pi / 2, lane_id="S_in_0")
    assert closest_heading(cands, math.pi / 2).label == "go straight through the junction"
    ego = S.ego_state(x_m=1.6, y_m=-30.0, yaw_rad=math.pi / 2, lane_id="S_in_0")
    route = route_candidate(m, ego)
    assert route.lane_ids == ("S_in_0", ":J_1_0", "W_out_0")


def test_time_parameterize_progress_speed_limit_and_curves() -> None:
    m = S.arc_road(radius_m=20.0, speed_mps=15.0)
    (cand,) = candidates_for_pose(m, x_m=0.0, y_m=0.0, yaw_rad=0.0, lane_id="A_0")
    rows = time_parameterize(cand.sample(200), v0_mps=2.0, v_max_mps=15.0, a_max_mps2=1.5,
                             a_lat_max_mps2=2.0, horizon=40, dt_s=0.1)
    assert rows.shape == (41, 4)
    step = np.hypot(*np.diff(rows[:, :2], axis=0).T)
    assert np.all(step > 0.0)  # monotone progress
    assert np.all(np.diff(rows[:, 3]) <= 1.5 * 0.1 + 1e-9)
    assert rows[:, 3].max() <= math.sqrt(2.0 * 20.0) + 0.3  # curve cap, not 15 m/s


def test_forecast_of_an_agent_past_its_curve_goes_on_from_where_it_is() -> None:
    """A decision's curve of an agent is a few seconds old: an agent already 10 m past
    its end is forecast on from its own position along the curve's continuation (it
    started at the curve's end, 10 m behind the agent, before)."""
    from lmpc_mpc.prediction import predict_along

    cps = ((0.0, 0.0), (10.0, 0.0), (20.0, 5.0), (30.0, 5.0))
    xy = predict_along(cps, v_mps=5.0, horizon=10, dt_s=0.1, start_xy_m=(40.0, 5.0))
    assert xy[0] == pytest.approx((40.0, 5.0), abs=0.05)
    assert xy[-1] == pytest.approx((45.0, 5.0), abs=0.1)
    on = predict_along(cps, v_mps=5.0, horizon=10, dt_s=0.1, start_xy_m=(0.0, 0.0))
    assert on[0] == pytest.approx((0.0, 0.0), abs=0.05)


def test_a_decision_curve_taking_effect_later_starts_from_the_ego_and_cuts_less() -> None:
    """A turn candidate made 40-50 m before the junction takes effect 2.5 s later, the ego
    10-15 m before it: rebased on the ego's position the curve keeps closer to the lane
    through the turn than the stale one (whose long first leg bends it early)."""
    from lmpc_mpc.controller import rebased_control_points

    m = S.four_way_junction()
    lanes = {ln.id: ln for ln in m.lanes}
    for y_asked, y_now, gain_m in ((-40.0, -15.0, 0.08), (-50.0, -10.0, 0.3)):
        cands = candidates_for_pose(m, x_m=1.6, y_m=y_asked, yaw_rad=math.pi / 2,
                                    lane_id="S_in_0")
        left = {c.label: c for c in cands}["turn left at the junction"]
        centre = _Polyline.of(np.vstack([np.asarray(lanes[i].centerline)
                                         for i in left.lane_ids]))
        rebased = rebased_control_points(left.control_points, 1.6, y_now)
        assert rebased[0] == pytest.approx((1.6, y_now))
        assert rebased[-1] == pytest.approx(left.control_points[-1])

        def dev(cps: object) -> float:
            pts = bezier_points(cps, 400)
            return max(centre.project(float(x), float(y))[1] for x, y in pts if y > y_now)

        assert dev(rebased) < dev(left.control_points) - gain_m
    # the ego still at the first control point, or past the last but one: kept as is;
    # just past the first: the first is replaced by the ego's position
    cps = ((0.0, 0.0), (10.0, 0.0), (20.0, 5.0))
    assert np.allclose(rebased_control_points(cps, 0.0, 0.0), cps)
    assert np.allclose(rebased_control_points(cps, 25.0, 5.0), cps)
    assert np.allclose(rebased_control_points(cps, 0.5, 0.1), ((0.5, 0.1),) + cps[1:])


def test_an_agent_going_against_its_lane_is_forecast_along_its_heading() -> None:
    """Issue 23 (si 20 at a 2.5 s latency): a pedestrian walking a crossing against the
    crossing lane's drawn direction was forecast walking backwards, away from the ego's
    path, and walked into the ego. An agent heading more than 90 degrees off every
    candidate of its lane is forecast straight on along its heading; one going the lane's
    way keeps the lane candidate."""
    from lmpc_mpc.prediction import forecast

    m = S.straight_road()
    wrong = S.agent("ped", x_m=100.0, y_m=1.6, yaw_rad=0.0, v_mps=1.2, lane_id="-E0_0",
                    length_m=0.5, width_m=0.5)  # walking east on the westbound lane
    xy = forecast(wrong, None, map_=m, horizon=30, dt_s=0.1).xy_m
    assert xy[-1][0] == pytest.approx(100.0 + 3.6, abs=0.05)  # east, not west
    assert xy[-1][1] == pytest.approx(1.6, abs=0.05)
    right = wrong.model_copy(update={"yaw_rad": math.pi})
    xy = forecast(right, None, map_=m, horizon=30, dt_s=0.1).xy_m
    assert xy[-1][0] == pytest.approx(100.0 - 3.6, abs=0.05)


def test_the_hot_path_gradient_is_numpys_to_the_last_bit() -> None:
    from lmpc_mpc.reference import _gradient

    rng = np.random.default_rng(3)
    for n in (2, 3, 601):
        for ds in (0.1, 0.5, 0.37):
            f = rng.normal(scale=100.0, size=(n, 2))
            assert np.array_equal(_gradient(f, ds), np.gradient(f, ds, axis=0))
            assert np.array_equal(_gradient(_gradient(f, ds), ds),
                                  np.gradient(np.gradient(f, ds, axis=0), ds, axis=0))
    with pytest.raises(ValueError, match="two samples"):
        _gradient(np.zeros((1, 2)), 0.1)


def test_the_lane_lookup_near_a_point_finds_what_scanning_every_lane_finds() -> None:
    """``_locate`` projects only onto the lanes whose grown bounding box holds the point
    (a city map has hundreds): the same lane and arc length as projecting onto all."""
    from lmpc_mpc.reference import MAX_HEADING_OFF_RAD, _index, _locate, _wrap

    def scan_all(idx, x: float, y: float, yaw: float):  # the lookup before the boxes
        best = None
        for lid, line in idx.lines.items():
            s, dist, heading = line.project(x, y)
            off = abs(_wrap(heading - yaw))
            if off > MAX_HEADING_OFF_RAD or dist > idx.lanes[lid].width_m * 0.5 + 2.0:
                continue
            if best is None or dist + 2.0 * off < best[0]:
                best = (dist + 2.0 * off, lid, s)
        return None if best is None else (best[1], best[2])

    rng = np.random.default_rng(5)
    found = 0
    for m in (S.four_way_junction(), S.roundabout_entry(), S.straight_road()):
        idx = _index(m)
        lines = list(idx.lines.values())
        for _ in range(400):  # near a lane (within ~3 m, sometimes beyond its reach)
            pts = lines[rng.integers(len(lines))].pts
            i = int(rng.integers(len(pts) - 1))
            x, y = pts[i] + rng.normal(0.0, 3.0, size=2)
            d = pts[i + 1] - pts[i]
            yaw = math.atan2(d[1], d[0]) + rng.normal(0.0, 0.5)
            got = _locate(idx, float(x), float(y), float(yaw), None)
            assert got == scan_all(idx, float(x), float(y), float(yaw))
            found += got is not None
    assert 600 < found < 1200  # most points were on a lane, some on none


def test_a_bad_reference_path_is_named_and_its_geometry_is_the_one_used() -> None:
    """``reference_path_points`` refuses what ``timed_reference`` refuses, by name, before
    the controller resamples a path; a resampling passed in (``geometry``) gives the same
    reference as the one computed inside, bit for bit."""
    from lmpc_mpc.reference import (REFERENCE_DS_M, ReferencePathError, _path_geometry,
                                    reference_path_points, timed_reference)

    with pytest.raises(ReferencePathError, match="NaN or infinite"):
        reference_path_points(np.array([[0.0, 0.0], [np.nan, 1.0]]))
    with pytest.raises(ReferencePathError, match=r"m>=2, 2"):
        reference_path_points(np.array([[0.0, 0.0]]))
    xs = np.linspace(0.0, 60.0, 121)
    path = np.column_stack([xs, 0.02 * xs ** 1.5])
    kw = dict(v0_mps=8.0, v_max_mps=13.9, a_max_mps2=1.5, a_lat_max_mps2=2.0, horizon=30,
              dt_s=0.1)
    inside = timed_reference(path, **kw)
    passed = timed_reference(path, geometry=_path_geometry(reference_path_points(path),
                                                           REFERENCE_DS_M), **kw)
    assert np.array_equal(inside.states, passed.states)
    assert np.array_equal(inside.curvature_1pm, passed.curvature_1pm)
