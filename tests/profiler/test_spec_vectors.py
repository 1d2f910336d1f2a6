"""The profiler against every expected figure of the spec sheet: §6.3 histogram, §6.4 synthetic trace,
§4.4 thesis listings, §6.5 report block beside the profiler's figures."""

from __future__ import annotations

import pytest

from hilbench.profiler.histogram import px4_histogram, px4_lines
from hilbench.profiler.settings import ProfilerSettings


def test_px4_histogram_vector_63():
    values = [0, 1, 2, 3, 5, 6, 10, 11, 20, 21, 50, 51, 100, 101, 1000, 1001, 65535]
    h = px4_histogram(values)
    assert [h[k] for k in ("<=1", "<=2", "<=5", "<=10", "<=20", "<=50", "<=100", "<=1000", ">1000")] == \
        [2, 1, 2, 2, 2, 2, 2, 2, 2]
    assert h["early"] == 0
    assert px4_lines(h)[0] == "<=1: 2" and px4_lines(h)[-1] == ">1000: 2"
    assert px4_histogram([-3, 0.5, 1.5], tick=1)["early"] == 1
    assert px4_histogram([2160], tick=216)["<=10"] == 1  # ticks of 216 cycles... or any unit


def test_synthetic_trace_64_every_expected_figure(spec):
    a, _ = spec.profile(spec.lines(spec.TRACE_64), spec.SETTINGS_64)
    q = a.quality
    assert q["out_of_order"] == 2
    assert (q["edge_orphan_ends"], q["edge_orphan_begins"], q["orphan_ends"], q["orphan_begins"]) == (1, 1, 0, 0)
    assert a.t[a.pairing.orphan_end_pos].tolist() == [0] and a.t[a.pairing.orphan_begin_pos].tolist() == [5011]
    assert not q["untrustworthy"]
    assert a.window["W_us"] == 5011 and a.window["denominator"] == "span"

    wc, idle, tsink, pid = (a.tasks[n] for n in ("wheel_ctrl", "IDLE", "tsink", "pid"))
    assert (wc["count"], wc["total_us"], wc["min_us"], wc["max_us"]) == (7, 72, 9, 12)
    assert wc["mean_us"] == pytest.approx(10.2857, abs=1e-4) and wc["share"] == pytest.approx(1.4368, abs=1e-4)
    assert (idle["count"], idle["total_us"], idle["min_us"], idle["max_us"]) == (5, 4929, 960, 1003)
    assert idle["mean_us"] == pytest.approx(985.8) and idle["share"] == pytest.approx(98.3636, abs=1e-4)
    assert (tsink["count"], tsink["total_us"]) == (1, 10) and tsink["share"] == pytest.approx(0.1996, abs=1e-4)
    assert a.window["task_share_sum"] == pytest.approx(100.0)
    assert [s["kind"] for s in a.tasks.values()] == ["task", "task", "task", "function"]

    b, e = a.intervals("pid")
    assert (e - b).tolist() == [5, 23] and (pid["total_us"], pid["mean_us"]) == (28, 14)
    assert a.net[a.pairing.name == a.names.index("pid")].tolist() == [5, 13]
    assert (pid["net_total_us"], pid["owner"], pid["net_preemption_not_removed"]) == (18, "wheel_ctrl", 0)

    jb = a.jobs["wheel_ctrl"]
    assert jb.a.tolist() == [0, 1003, 1998, 3010, 4000, 5001]
    assert jb.response.tolist() == [10, 12, 9, 30, 11, 10]
    assert jb.c.tolist() == [10, 12, 9, 20, 11, 10]
    assert jb.fragments.tolist() == [1, 1, 1, 2, 1, 1] and wc["jobs"] == 6

    assert (wc["period_mean_us"], wc["period_min_us"], wc["period_max_us"]) == (1000.2, 990, 1012)
    assert wc["freq_hz"] == pytest.approx(5 / 5001e-6) and round(wc["freq_hz"], 2) == 999.80
    assert (wc["jitter_us"], wc["jitter_abs_us"], wc["jitter_p99_p1_us"]) == (22, 12, 22)
    assert wc["jitter_std_us"] == pytest.approx(8.3487, abs=1e-4)
    assert (wc["release_latency_min_us"], wc["release_latency_max_us"]) == (-2, 10)
    lat = wc["histograms"]["latency"]
    assert (lat["<=1"], lat["<=5"], lat["<=10"], lat["early"]) == (3, 1, 1, 1)
    assert sum(lat[k] for k in lat if k not in ("<=1", "<=5", "<=10", "early")) == 0
    assert wc["deadline_misses"] == 1 and wc["deadline_offenders"] == [{"k": 4, "at_us": 3010, "value_us": 30}]
    assert a.deadline_misses["wheel_ctrl"] == [(3040, 30, 25)]
    relaxed, _ = spec.profile(spec.lines(spec.TRACE_64), spec.SETTINGS_64.with_(deadlines={}))
    assert relaxed.tasks["wheel_ctrl"]["deadline_misses"] == 0  # D = T

    thesis = {n: round(s["thesis_pct"], 4) for n, s in a.tasks.items()}
    assert thesis == {"IDLE": 97.8170, "wheel_ctrl": 1.4289, "pid": 0.5557, "tsink": 0.1985}


@pytest.mark.parametrize(("listing", "tasks", "stamps", "ooo", "orphans", "slices"), [
    ("LISTING_34", {"IDLE", "profile", "tsink"}, 11, 5, {"edge_end": [("IDLE", 1)]},
     {"profile": [26], "IDLE": [303], "tsink": [3], "w_ctrl": [91], "odom": [18]}),
    ("LISTING_35", {"IDLE", "profile", "tsink", "uros"}, 13, 0, {"edge_end": [("IDLE", 1)]},
     {"profile": [26], "IDLE": [527, 42], "tsink": [3], "uros": [62], "odom": [81]}),
    ("LISTING_38", None, 19, 0, {"edge_end": [("IDLE", 1)], "edge_begin": [("wheel_ctrl", 313), ("odometry", 788)]},
     {"profile": [23], "IDLE": [61, 181], "hal_fetch": [6, 6], "wheel_ctrl": [10], "odometry": [7],
      "pose_control": [9]}),
    ("LISTING_39", None, 26, 0, {},
     {"profile": [26], "IDLE": [7, 58, 71], "tsink": [3, 4], "pose_control": [9, 9], "odometry": [7],
      "hal_fetch": [7, 12], "wheel_ctrl": [11, 10]}),
])
def test_thesis_listings_give_the_stated_slices(spec, listing, tasks, stamps, ooo, orphans, slices):
    settings = ProfilerSettings(tasks=frozenset(tasks)) if tasks else ProfilerSettings()
    a, p = spec.profile(spec.lines(getattr(spec, listing)), settings)
    assert a.quality["stamps"] == stamps and a.quality["out_of_order"] == ooo
    got = {n: (lambda be: (be[1] - be[0]).tolist())(a.intervals(n)) for n in a.tasks}
    assert got == slices
    pos = a.pairing
    ends = [(a.names[a.ids[i]], int(a.t[i])) for i in pos.orphan_end_pos[pos.orphan_end_edge]]
    begins = [(a.names[a.ids[i]], int(a.t[i])) for i in pos.orphan_begin_pos[pos.orphan_begin_edge]]
    assert ends == orphans.get("edge_end", []) and begins == orphans.get("edge_begin", [])
    assert a.quality["orphan_ends"] == a.quality["orphan_begins"] == a.quality["double_begins"] == 0


def test_listings_38_39_agree_with_table_9_means(spec):
    """§4.4: the slices agree with the cached FreeRTOS means of Table 9 (hal_fetch 6.61, wheel_ctrl 10.69 ...)."""
    slices: dict[str, list[int]] = {}
    for listing in (spec.LISTING_38, spec.LISTING_39):
        a, _ = spec.profile(spec.lines(listing))
        for name in a.tasks:
            b, e = a.intervals(name)
            slices.setdefault(name, []).extend((e - b).tolist())
    table9 = {"hal_fetch": 6.61, "wheel_ctrl": 10.69, "odometry": 6.84, "pose_control": 9.88, "tsink": 3.01}
    for name, mean in table9.items():
        assert sum(slices[name]) / len(slices[name]) == pytest.approx(mean, abs=1.5), name


def test_listing_38_periods_of_section_43(spec):
    """§4.3: wheel_ctrl starts 96 and 313 µs (217 µs apart), odometry 289 and 788 µs (499 µs apart)."""
    a, _ = spec.profile(spec.lines(spec.LISTING_38), ProfilerSettings(periods={"wheel_ctrl": 200, "odometry": 500}))
    # Activations include the open begins' slices only once closed; use the stamps directly for the begins.
    begins = {n: [int(a.t[i]) for i in range(len(a.t)) if a.begin[i] and a.names[a.ids[i]] == n]
              for n in ("wheel_ctrl", "odometry")}
    assert begins == {"wheel_ctrl": [96, 313], "odometry": [289, 788]}
    a39, _ = spec.profile(spec.lines(spec.LISTING_39))
    assert a39.tasks["wheel_ctrl"]["period_mean_us"] == 89 and a39.tasks["pose_control"]["period_mean_us"] == 196
    assert a39.tasks["wheel_ctrl"]["freq_hz"] == pytest.approx(1e6 / 89)


def test_report_65_beside_the_profiler(spec):
    stamps = spec.lines(spec.LISTING_38)
    a, p = spec.profile(stamps + spec.REPORT_65, chunk=7)
    rs = a.runtime_stats
    assert a.classification == "report"  # task names came from the report's tables
    assert a.quality["reports"] == 1 and a.quality["parse_errors"] == 0
    assert (rs["free_heap"], rs["ctx_switches"], rs["closing"], rs["closing_us"]) == \
        (195696, 76148, "output took", 18779120)
    assert rs["total_abs"] == 211638 and rs["pct_matches_recomputed"]
    assert len(rs["tasks"]) == 9 and "Tmr Svc" in rs["tasks"]
    idle = rs["tasks"]["IDLE"]
    assert (idle["abs"], idle["pct_printed"], idle["pct_recomputed"]) == (201086, 95, 95)
    assert idle["kernel_share"] == pytest.approx(201086 / 211638 * 100)
    assert idle["abs_us"] == pytest.approx(201086 * 10001 / 108)
    assert idle["profiler_total_us"] == 61 + 181
    assert idle["profiler_share"] == pytest.approx((61 + 181) / (788 - 1) * 100)
    assert idle["diff_pp"] == pytest.approx(idle["profiler_share"] - idle["kernel_share"])
    assert (idle["state"], idle["priority"], idle["stack_hwm"], idle["number"]) == ("R", 0, 108, 8)
    # 19 hook stamps against 76,148 ctx switches: the rest were never received (an excerpt).
    assert rs["hook_stamps"] == 19 and rs["estimated_drops"] == 76148 - 19
    assert a.quality["estimated_drops"] == 76148 - 19 and a.quality["untrustworthy"]


def test_profiled_for_denominator(spec):
    report = spec.REPORT_65.replace(b"output took 18779120 us\n",
                                    b"profiled for 5011 us\n=============================================\n")
    s = spec.SETTINGS_64.with_(denominator="profiled")
    a, _ = spec.profile(spec.lines(spec.TRACE_64) + report, s)
    assert a.window["denominator"] == "profiled for" and a.window["W_us"] == 5011
    b, _ = spec.profile(spec.lines(spec.TRACE_64), s)
    assert b.window["denominator"].startswith("span") and b.window["W_us"] == 5011
    c, _ = spec.profile(spec.lines(spec.TRACE_64), spec.SETTINGS_64.with_(denominator=10022))
    assert c.tasks["IDLE"]["share"] == pytest.approx(98.3636 / 2, abs=1e-4)
