"""Pairing: the vectorised implementation agrees with the one-stamp-at-a-time definition, and the rules for
double begins, lost stamps, edge orphans, nesting and windows hold; net time agrees with its definition."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from hilbench.profiler.pairing import pair, pair_reference
from hilbench.profiler.settings import ProfilerSettings
from hilbench.profiler.stats import net_durations


def _same(a, b) -> None:
    for field in a._fields:
        assert np.array_equal(getattr(a, field), getattr(b, field)), field


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 4), st.booleans(), st.integers(0, 1)), max_size=60),
       st.lists(st.booleans(), min_size=5, max_size=5))
def test_vectorised_pairing_agrees_with_the_definition(stamps, task_flags):
    stamps.sort(key=lambda s: s[2])  # windows come one after the other
    ids = np.array([s[0] for s in stamps], dtype=np.int32)
    begin = np.array([s[1] for s in stamps], dtype=bool)
    seg = np.array([s[2] for s in stamps], dtype=np.int32)
    is_task = np.array(task_flags, dtype=bool)
    _same(pair(ids, begin, seg, is_task), pair_reference(ids, begin, seg, is_task))


def _run(text: str, tasks: set[str]):
    names = sorted({w.split()[0] for w in text.split(";")})
    toks = [w.split() for w in text.split(";")]
    ids = np.array([names.index(n) for n, _ in toks], dtype=np.int32)
    begin = np.array([e == "in" for _, e in toks])
    seg = np.zeros(len(ids), np.int32)
    p = pair(ids, begin, seg, np.array([n in tasks for n in names]))
    iv = [(names[n], int(b), int(e)) for n, b, e in zip(p.name, p.b_pos, p.e_pos, strict=True)]
    return p, iv


def test_task_double_begin_discards_the_older_begin():
    p, iv = _run("A in;A out;A in;A in;A out;A out", {"A"})
    assert iv == [("A", 0, 1), ("A", 3, 4)]
    assert p.double_begin_pos.tolist() == [2]
    assert p.orphan_end_pos.tolist() == [5] and p.orphan_end_edge.tolist() == [False]  # a lost begin


def test_function_lifo_nesting_and_edges():
    # f recursion: f(f()) nests; an end before any begin is an edge orphan; one left open at the end is too.
    p, iv = _run("f out;f in;f in;f out;f out;f in", set())
    assert iv == [("f", 1, 4), ("f", 2, 3)]
    assert p.orphan_end_edge.tolist() == [True] and p.orphan_begin_edge.tolist() == [True]
    # A lost end: an open begin that is not the last stamp of its name is not an edge orphan.
    p, iv = _run("g in;g in;g out", set())
    assert iv == [("g", 1, 2)] and p.orphan_begin_edge.tolist() == [False]


def test_windows_never_pair_across():
    ids = np.zeros(4, np.int32)
    begin = np.array([True, False, True, False])
    seg = np.array([0, 1, 1, 1], np.int32)
    p = pair(np.array([0, 0, 0, 0], np.int32), np.array([True, True, False, False]), seg, np.array([True]))
    assert p.count == 1 and p.b_pos.tolist() == [1] and p.e_pos.tolist() == [2]
    assert p.orphan_begin_pos.tolist() == [0] and p.orphan_end_pos.tolist() == [3]
    assert pair(ids, begin, np.zeros(4, np.int32), np.array([False])).count == 2


def _net_reference(t, is_task, name, b_pos, e_pos):
    """§5.2 by brute force: owner running time inside [b, e] minus owner time inside direct children."""
    slices = [(int(b_pos[k]), int(e_pos[k]), int(name[k])) for k in range(len(name)) if is_task[name[k]]]
    funcs = [k for k in range(len(name)) if not is_task[name[k]]]

    def run_time(o, x0, x1):
        return sum(max(0, min(t[e], x1) - max(t[b], x0)) for b, e, n in slices if n == o)

    out = {}
    for k in funcs:
        b, e = int(b_pos[k]), int(e_pos[k])
        owner = next((n for sb, se, n in slices if sb < b < se), None)
        inside = [j for j in funcs if j != k and b < b_pos[j] and e_pos[j] < e]
        direct = [j for j in inside if not any(b_pos[i] < b_pos[j] and e_pos[j] < e_pos[i] for i in inside if i != j)]
        if owner is None:
            out[k] = (t[e] - t[b]) - sum(t[e_pos[j]] - t[b_pos[j]] for j in direct)
        else:
            out[k] = run_time(owner, t[b], t[e]) - sum(run_time(owner, t[b_pos[j]], t[e_pos[j]]) for j in direct)
    return out


def test_net_time_agrees_with_its_definition():
    rng = np.random.default_rng(5)
    # Two tasks alternating with gaps; nested function scopes inside task A, sometimes preempted by B.
    text = []
    t = 0
    for _ in range(40):
        text.append(("A", t, True))
        depth = 0
        for _ in range(rng.integers(0, 4)):
            t += int(rng.integers(1, 5))
            if depth and rng.random() < 0.5:
                text.append((f"f{depth - 1}", t, False))
                depth -= 1
            else:
                text.append((f"f{depth}", t, True))
                depth += 1
            if rng.random() < 0.3:  # preemption by B
                text.append(("A", t, False))
                text.append(("B", t, True))
                t += int(rng.integers(1, 5))
                text.append(("B", t, False))
                text.append(("A", t, True))
        while depth:
            t += int(rng.integers(1, 5))
            depth -= 1
            text.append((f"f{depth}", t, False))
        t += 2
        text.append(("A", t, False))
        t += int(rng.integers(1, 9))
    names = sorted({n for n, _, _ in text})
    ids = np.array([names.index(n) for n, _, _ in text], dtype=np.int32)
    tt = np.array([x[1] for x in text], dtype=np.int64)
    begin = np.array([x[2] for x in text])
    is_task = np.array([n in ("A", "B") for n in names])
    p = pair(ids, begin, np.zeros(len(ids), np.int32), is_task)
    net, owner, fallback = net_durations(tt, is_task, p.name, p.b_pos, p.e_pos)
    ref = _net_reference(tt, is_task, p.name, p.b_pos, p.e_pos)
    assert len(ref) > 20 and not fallback.any()
    assert {k: int(net[k]) for k in ref} == {k: int(v) for k, v in ref.items()}
    assert set(owner[~is_task[p.name]].tolist()) == {names.index("A")}


def test_net_time_without_task_stamps_subtracts_children(spec):
    a, _ = spec.profile(b"outer 0 in\ninner 2 in\ninner 5 out\nouter 10 out\n", ProfilerSettings(tasks=frozenset()))
    assert a.tasks["outer"]["net_total_us"] == 7 and a.tasks["outer"]["net_preemption_not_removed"] == 1
    assert a.tasks["inner"]["net_total_us"] == 3


def test_net_time_on_a_trace_longer_than_2_pow_31_us():
    """An hour-long run: the owner's running time must not wrap in 32-bit arithmetic (it used to raise)."""
    from hilbench.profiler.ingest import Profiler

    lines = []
    for k in range(3):
        t = k * 1_500_000_000  # 25 minutes apart: the last job is at 3e9 us > 2^31
        lines += [f"uros {t} in", f"w_ctrl {t + 1} in", f"w_ctrl {t + 5} out", f"uros {t + 9} out",
                  f"IDLE {t + 10} in", f"IDLE {t + 1_000_000} out"]
    p = Profiler(ProfilerSettings(tasks=frozenset({"uros", "IDLE"})))
    p.feed(("\n".join(lines) + "\n").encode())
    p.finish()
    a = p.analyse()
    w = a.tasks["w_ctrl"]
    assert w["count"] == 3 and w["net_mean_us"] == 4.0 and w["mean_us"] == 4.0
