#!/usr/bin/env python3
"""Long-running fuzzing of every decoder and instrument that reads outside bytes.

The targets come from the ``hilbench.fuzz_targets`` registry (:mod:`hilbench.fuzzing`): the
Dynamixel 2.0 and 1.0 decoders, Vel2d framing, the text, binary and mixed trace-stamp
decoders, the capture parser, the Dynamixel bus monitor's tracker and the trace profiler,
and whatever a family registers later (one entry-point line). Each target gets two phases:

1. **Fuzzing** (``--inputs`` per target): with atheris (``pip install -e '.[fuzz]'``), a
   coverage-guided libFuzzer run in a worker process per target, started from a corpus of
   the target's own clean traffic, damaged copies of it and noise; without atheris (or
   ``--engine random``), a seeded loop of random, damaged (bits flipped, bytes replaced,
   lost, added, cut) and spliced inputs. Every input is fed in random pieces; any
   exception is counted, its first traceback printed and the input saved under
   ``fuzz-findings/`` (a target's one-line refusals by design, such as a capture
   header of a newer format version, are counted apart as ``refusals``).
2. **Figures** (``--measure`` inputs per kind): throughput on noise and on damaged
   traffic against the target's fastest line, and the resync cost: good items (packets,
   frames, stamps, records) lost per damaged byte, and bytes dropped per damaged byte.
   A decoder that resynchronises one byte after a bad candidate loses about the item a
   damaged byte hits; a length field that swallowed the next items would cost more.

Servers (targets of kind ``server``: the socketcand daemon, the RFC 2217 server, a SCIP unit
over TCP, the XRCE agent, an RTPS participant, the control channel with each family's commands
and with all of them on one bench) get the first phase only:
each input is a client's session, mutated, driven through the code the bench runs; a traceback
the server merely logs, or a thread it loses, counts as one raised. Inputs are cut to the
target's own bound where it has one (``max_input``: a kB of a session walks its states).

Prints one line per target, one JSON figure per target and kind (``fuzz_<target>_inputs``:
inputs tried against those asked for; ``fuzz_<target>_tracebacks``: inputs that raised, against
the inputs tried; the rule is 0), as the other tools print them, then a table and, last, one
JSON document (``--json FILE`` writes it too). Exit status 1 if any input raised.

Usage: tools/fuzz.py [--inputs N] [--targets A,B|servers|all] [--engine atheris|random] [--jobs J]
                     [--max-len BYTES] [--measure N] [--seed S] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchlib import emit  # noqa: E402 (the tools' shared figure line)

FINDINGS = REPO / "fuzz-findings"
WOLFGANG = REPO / "tests/data/dynamixel/wolfgang_trace.bin"


# --------------------------------------------------------------------------- inputs


def chunker(rng: random.Random):
    """Piece sizes for one input: mostly small reads, now and then one large (any split must work)."""
    style = rng.random()
    if style < 0.3:
        return lambda: 1 << 30  # the whole input at once
    if style < 0.6:
        return lambda: rng.randrange(1, 17)
    return lambda: rng.choice((1, 3, 64, 512, 4096, 65536))


def seeds(target, rng: random.Random, count: int = 8, size: int = 2048) -> list[bytes]:
    """Clean traffic of the target (and the Wolfgang capture for the Dynamixel readers)."""
    out = [target.sample(rng, rng.randrange(64, size)) for _ in range(count)]
    if target.name in ("dynamixel", "monitor-dynamixel") and WOLFGANG.exists():
        data = WOLFGANG.read_bytes()
        out += [data[i : i + size] for i in range(0, len(data), len(data) // count)][:count]
    return out


def random_input(rng: random.Random, pool: list[bytes], target, max_len: int) -> bytes:
    """Noise, a damaged seed, two seeds spliced, or a seed cut short."""
    from hilbench.fuzzing import mutate

    k = rng.random()
    if k < 0.25:
        return target.noise(rng, rng.randrange(0, max_len))
    seed = rng.choice(pool)[:max_len]
    if k < 0.8:
        return mutate(rng, seed, rate=rng.choice((0.0005, 0.005, 0.02, 0.1)))
    if k < 0.9:
        other = rng.choice(pool)
        return (seed[: rng.randrange(len(seed) + 1)] + other[rng.randrange(len(other) + 1) :])[:max_len]
    return seed[: rng.randrange(len(seed) + 1)]


# --------------------------------------------------------------------------- running one input


class Stats:
    """What fuzzing one target found."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.inputs = 0
        self.bytes = 0
        self.exceptions = 0
        self.refusals = 0
        self.first: str | None = None
        self.seconds = 0.0

    def run(self, target, data: bytes, rng: random.Random) -> None:
        from hilbench.fuzzing import run

        self.inputs += 1
        self.bytes += len(data)
        try:
            run(target.make(), data, chunker(rng))
        except target.refuses as exc:  # by design: a one-line refusal (a capture of a newer version)
            self.refusals += 1
            if "\n" in str(exc):
                raise
        except Exception:  # noqa: BLE001 (what the fuzzer is for)
            self.exceptions += 1
            FINDINGS.mkdir(exist_ok=True)
            path = FINDINGS / f"{self.name}-{self.exceptions}.bin"
            path.write_bytes(data)
            if self.first is None:
                self.first = traceback.format_exc() + f"(input saved to {path})"
                print(f"{self.name}: exception on a {len(data)}-byte input:\n{self.first}", file=sys.stderr)

    def doc(self) -> dict:
        return {"inputs": self.inputs, "bytes": self.bytes, "exceptions": self.exceptions,
                "refusals": self.refusals, "seconds": round(self.seconds, 1), "first_exception": self.first}


def bound(target, max_len: int) -> int:
    """The longest input for ``target``: the fuzzer's bound, or the target's own if smaller."""
    return min(max_len, target.max_input) if target.max_input else max_len


def fuzz_random(target, inputs: int, max_len: int, seed: int) -> Stats:
    rng = random.Random(seed)
    max_len = bound(target, max_len)
    pool = seeds(target, rng, size=max(65, min(2048, max_len)))
    stats = Stats(target.name)
    t0 = time.monotonic()
    for _ in range(inputs):
        stats.run(target, random_input(rng, pool, target, max_len), rng)
    stats.seconds = time.monotonic() - t0
    return stats


def fuzz_random_in_worker(name: str, inputs: int, max_len: int, seed: int) -> dict:
    """:func:`fuzz_random` in a worker process (``--jobs`` with the random engine): its figures as a dict."""
    from hilbench.fuzzing import targets

    target = next(t for t in targets() if t.name == name)
    return fuzz_random(target, inputs, max_len, seed).doc()


def stats_from(name: str, doc: dict) -> Stats:
    stats = Stats(name)
    stats.inputs, stats.bytes, stats.exceptions = doc["inputs"], doc["bytes"], doc["exceptions"]
    stats.refusals, stats.seconds, stats.first = doc["refusals"], doc["seconds"], doc["first_exception"]
    return stats


# --------------------------------------------------------------------------- atheris worker


#: Inputs per atheris worker process: libFuzzer's memory grows with its run (coverage features of the
#: instrumented Python code), so a long run is made of workers that share one corpus directory.
SEGMENT = 10_000


def atheris_worker(name: str, inputs: int, max_len: int, seed: int, out: Path, corpus: Path) -> None:
    """One target under libFuzzer (coverage-guided), in this process; stats written to ``out``."""
    import atheris

    with atheris.instrument_imports(include=["hilbench"]):
        from hilbench.fuzzing import targets

        target = next(t for t in targets() if t.name == name)
        target.make()  # import everything it uses while instrumenting
    stats = Stats(name)
    t0 = time.monotonic()

    def save() -> None:
        stats.seconds = time.monotonic() - t0
        out.write_text(json.dumps(stats.doc()))

    def one_input(data: bytes) -> None:
        stats.run(target, data, random.Random(seed * 1_000_003 + stats.inputs))
        if stats.inputs % 1000 == 0 or stats.inputs >= inputs:
            save()

    save()
    atheris.Setup([sys.argv[0], f"-runs={inputs}", f"-max_len={max_len}", f"-seed={seed}", "-timeout=30",
                   "-rss_limit_mb=4096", "-print_final_stats=0", "-close_fd_mask=3", str(corpus)], one_input)
    atheris.Fuzz()


def fuzz_atheris(name: str, inputs: int, max_len: int, seed: int) -> Stats:
    """``inputs`` coverage-guided inputs for one target, in workers of :data:`SEGMENT` inputs sharing a
    corpus (seeded with the target's own traffic, damaged copies and noise)."""
    from hilbench.fuzzing import mutate, targets

    target = next(t for t in targets() if t.name == name)
    max_len = bound(target, max_len)
    stats = Stats(name)
    with tempfile.TemporaryDirectory() as tmp:
        corpus = Path(tmp) / "corpus"
        corpus.mkdir()
        rng = random.Random(seed)
        for i, data in enumerate(seeds(target, rng)):
            (corpus / f"seed{i}").write_bytes(data[:max_len])
            (corpus / f"damaged{i}").write_bytes(mutate(rng, data[:max_len], rate=0.02))
        (corpus / "noise").write_bytes(target.noise(rng, 512))
        out = Path(tmp) / "stats.json"
        segment = 0
        while stats.inputs < inputs:
            runs = min(SEGMENT, inputs - stats.inputs)
            cmd = [sys.executable, __file__, "--worker", name, "--inputs", str(runs), "--max-len", str(max_len),
                   "--seed", str(seed + segment), "--stats", str(out), "--corpus", str(corpus)]
            proc = subprocess.run(cmd, capture_output=True, text=True)
            doc = json.loads(out.read_text()) if out.exists() else {"inputs": 0, "bytes": 0, "exceptions": 0,
                                                                     "refusals": 0, "seconds": 0,
                                                                     "first_exception": None}
            out.unlink(missing_ok=True)
            stats.inputs += doc["inputs"]
            stats.bytes += doc["bytes"]
            stats.exceptions += doc["exceptions"]
            stats.refusals += doc["refusals"]
            stats.seconds += doc["seconds"]
            stats.first = stats.first or doc["first_exception"]
            if proc.returncode != 0 and doc["inputs"] < runs:
                # the worker itself died (libFuzzer caught a crash, a time-out or memory running out)
                stats.exceptions += 1
                stats.first = stats.first or (proc.stderr or proc.stdout)[-3000:]
                print(f"{name}: worker died after {doc['inputs']} of {runs} inputs:\n{(proc.stderr or '')[-1500:]}",
                      file=sys.stderr, flush=True)
                if doc["inputs"] == 0:
                    break
            segment += 1
    return stats


# --------------------------------------------------------------------------- figures


def measure(target, count: int, seed: int, size: int = 1 << 20) -> dict:
    """Throughput on ``size`` bytes of noise and of damaged traffic (1 % of the bytes), and the resync cost
    over ``count`` 16 KiB samples with 1-7 damaged bytes each."""
    from hilbench.fuzzing import mutate, run

    rng = random.Random(seed)
    ratios = {}
    for kind in ("noise", "damaged"):
        data = target.noise(rng, size) if kind == "noise" else mutate(rng, target.sample(rng, size))
        t0 = time.process_time()
        run(target.make(), data, 65536)
        ratios[kind] = len(data) / max(time.process_time() - t0, 1e-9) / target.line_rate
    lost = dropped = hits = 0
    for _ in range(count):
        clean = target.sample(rng, 16_384)
        n = rng.randrange(1, 8)
        bad = mutate(rng, clean, rate=n / len(clean))
        ref = run(target.make(), clean, 4096)
        got = run(target.make(), bad, 4096)
        lost += max(0, ref.good() - got.good())
        dropped += max(0, got.dropped() - ref.dropped())
        hits += n
    return {
        "noise_ratio": round(ratios["noise"], 1),
        "damaged_ratio": round(ratios["damaged"], 1),
        "items_lost_per_damaged_byte": round(lost / hits, 2),
        "bytes_dropped_per_damaged_byte": round(dropped / hits, 1),
        "line": target.line,
    }


# --------------------------------------------------------------------------- main


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--inputs", type=int, default=120_000, help="fuzz inputs per target (default 120000)")
    ap.add_argument("--targets", help="comma-separated target names, 'servers' for every server target, 'all' "
                                      "for every registered one (the default)")
    ap.add_argument("--engine", choices=("atheris", "random"), help="default: atheris if installed")
    ap.add_argument("--jobs", type=int, default=1, help="targets fuzzed at once (worker processes)")
    ap.add_argument("--max-len", type=int, default=4096, help="largest input in bytes")
    ap.add_argument("--measure", type=int, default=200, help="samples for the resync cost (0: no figures)")
    ap.add_argument("--size", type=int, default=1 << 20, help="bytes of noise and of damaged traffic for the "
                                                            "throughput figures (default 1 MiB)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", metavar="FILE", help="also write the JSON document to FILE")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--stats", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--corpus", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        atheris_worker(args.worker, args.inputs, args.max_len, args.seed, args.stats, args.corpus)
        return 0

    from hilbench.fuzzing import targets

    names = set(args.targets.split(",")) if args.targets and args.targets != "all" else None
    chosen = [t for t in targets() if names is None or t.name in names or ("servers" in names and t.kind == "server")]
    unknown = (names or set()) - {t.name for t in targets()} - {"servers"}
    if unknown:
        ap.error(f"no target named {', '.join(sorted(unknown))} (targets: {', '.join(t.name for t in targets())})")
    engine = args.engine
    if engine is None:
        try:
            import atheris  # noqa: F401
            engine = "atheris"
        except ImportError:
            engine = "random"
    print(f"fuzzing {len(chosen)} targets with {engine}, {args.inputs} inputs each", file=sys.stderr, flush=True)
    results: dict[str, dict] = {}
    t0 = time.monotonic()
    if engine == "atheris" and args.jobs > 1:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(args.jobs) as pool:
            found = dict(zip([t.name for t in chosen], pool.map(
                lambda t: fuzz_atheris(t.name, args.inputs, args.max_len, args.seed), chosen), strict=True))
    elif args.jobs > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(args.jobs) as pool:
            futures = {t.name: pool.submit(fuzz_random_in_worker, t.name, args.inputs, args.max_len, args.seed)
                       for t in chosen}
            found = {}
            for name, future in futures.items():
                found[name] = stats_from(name, future.result())
                s = found[name]
                print(f"  {name}: {s.inputs} inputs, {s.bytes / 1e6:.1f} MB, exceptions {s.exceptions} "
                      f"({s.seconds:.0f} s)", file=sys.stderr, flush=True)
                if s.first:
                    print(f"{name}: first exception:\n{s.first}", file=sys.stderr, flush=True)
    else:
        found = {}
        for t in chosen:
            found[t.name] = (fuzz_atheris(t.name, args.inputs, args.max_len, args.seed) if engine == "atheris"
                             else fuzz_random(t, args.inputs, args.max_len, args.seed))
            s = found[t.name]
            print(f"  {t.name}: {s.inputs} inputs, {s.bytes / 1e6:.1f} MB, exceptions {s.exceptions} "
                  f"({s.seconds:.0f} s)", file=sys.stderr, flush=True)
    for t in chosen:
        results[t.name] = {"kind": t.kind, **found[t.name].doc()}
        if args.measure and t.kind != "server":  # (a session's throughput against a line says little)
            results[t.name].update(measure(t, args.measure, args.seed, args.size))
    for name, r in results.items():
        tried = r["inputs"]
        emit(f"fuzz_{name}_inputs", tried, "inputs", args.inputs, tried / max(args.inputs, 1),
             seconds=r["seconds"], per_second=round(tried / max(r["seconds"], 1e-9)))
        emit(f"fuzz_{name}_tracebacks", r["exceptions"], "inputs", tried, r["exceptions"] / max(tried, 1))
    total = sum(r["inputs"] for r in results.values())
    exceptions = sum(r["exceptions"] for r in results.values())
    doc = {"engine": engine, "inputs": total, "exceptions": exceptions, "seconds": round(time.monotonic() - t0),
           "max_len": args.max_len, "seed": args.seed, "targets": results}
    w = max([20, *map(len, results)])
    print(f"{'target':{w}s} {'inputs':>9s} {'MB':>7s} {'exc':>4s} {'ref':>5s} {'noise x':>8s} {'damaged x':>9s} "
          f"{'lost/dmg':>8s} {'drop/dmg':>8s}")
    for name, r in results.items():
        print(f"{name:{w}s} {r['inputs']:9d} {r['bytes'] / 1e6:7.1f} {r['exceptions']:4d} {r['refusals']:5d} "
              f"{r.get('noise_ratio', float('nan')):8.1f} {r.get('damaged_ratio', float('nan')):9.1f} "
              f"{r.get('items_lost_per_damaged_byte', float('nan')):8.2f} "
              f"{r.get('bytes_dropped_per_damaged_byte', float('nan')):8.1f}")
    print(f"total: {total} inputs, exceptions: {exceptions}")
    print(json.dumps(doc))
    if args.json:
        Path(args.json).write_text(json.dumps(doc, indent=1) + "\n")
    return 1 if exceptions else 0


if __name__ == "__main__":
    os.environ.setdefault("PYTHONHASHSEED", "0")
    sys.exit(main())
