"""``gpsins montecarlo`` and ``gpsins sweep``: check the whole command line, then run the plan."""

from __future__ import annotations

import sys
from pathlib import Path

from ..errors import CommandError as UsageError


def split_values(text: str) -> list[str]:
    """Comma-separated TOML values; commas inside [...] and quotes do not split (``[0.2,0,-0.5],[0,0,0]``)."""
    out, depth, quote, cur = [], 0, None, []
    for ch in text:
        if quote:
            quote = None if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch == "[":
            depth += 1
        elif ch == "]":
            depth -= 1
        elif ch == "," and depth == 0:
            out.append("".join(cur).strip())
            cur = []
            continue
        cur.append(ch)
    out.append("".join(cur).strip())
    if any(not v for v in out):
        raise UsageError(f"--values {text}: an empty value; give v1,v2,... (TOML values)")
    return out


def seeds_of(n: int, first: int) -> list[int]:
    if n < 1:
        raise UsageError(f"--seeds {n}: at least one seed")
    return list(range(first, first + n))


def plan_from_args(args, sweep_key: str | None, sweep_texts: list[str]):
    """The checked plan: scenario loaded, configuration and every swept value validated as --set does."""
    from ..evaluate import outages
    from ..sim import scenario
    from ..nav import config as nav_config
    from .runner import Plan

    sc = scenario.load(args.scenario)
    modes = ["loose", "tight"] if args.mode == "both" else [args.mode]
    overrides = nav_config.parse_overrides(args.set or [])
    nav_config.load_config(args.config, overrides)
    if sweep_key:
        if not sweep_texts:
            raise UsageError("--values: give at least one value")
        if len(set(sweep_texts)) != len(sweep_texts):
            raise UsageError(f"--values {','.join(sweep_texts)}: a value is given twice")
        for v in sweep_texts:
            try:
                swept = nav_config.parse_overrides([f"{sweep_key}={v}"])
                nav_config.load_config(args.config, nav_config.merge(overrides, swept))
            except nav_config.ConfigError as e:
                raise UsageError(f"swept value {sweep_key}={v}: {str(e).replace('--set ', '')}") from None
    if args.outages:
        outages.parse(args.outages)
    if args.estimator:
        from ..nav import estimator

        estimator.load(args.estimator)  # a spec that cannot load fails here, not in every task
    if args.scheduler and args.workers:
        raise UsageError("--workers sizes the local cluster; an existing one (--scheduler) has its own workers")
    if args.workers is not None and args.workers < 1:
        raise UsageError(f"--workers {args.workers}: at least one")
    out = Path(args.out or f"out/montecarlo-{sc.name}")
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise UsageError(f"{out}: exists and is not empty; give a new --out directory")
    return Plan(scenario=sc, seeds=seeds_of(args.seeds, args.first_seed), out=out, modes=modes,
                config=_shipped_config(args.config),
                overrides=overrides, outages=args.outages, sweep_key=sweep_key,
                sweep_values=sweep_texts if sweep_key else [None], sweep_texts=sweep_texts if sweep_key else [""],
                grid_s=args.grid, keep=args.keep, estimator=args.estimator)


def _shipped_config(config: str | None):
    """A --config file as its table (workers elsewhere need not see the file); a preset by its name."""
    if config is None or not Path(config).is_file():
        return config
    import tomllib

    data = tomllib.loads(Path(config).read_text(encoding="utf-8"))
    return dict(data.get("filter", data))


def run(args) -> int:
    if args.command == "sweep":
        key, texts = args.key, split_values(args.values)
    elif getattr(args, "sweep", None):
        key, sep, values = args.sweep.partition("=")
        if not sep or not key.strip():
            raise UsageError(f"--sweep {args.sweep}: expected KEY=v1,v2,...")
        key, texts = key.strip(), split_values(values)
    else:
        key, texts = None, []
    plan = plan_from_args(args, key, texts)
    from .runner import open_client, run_plan

    where = args.scheduler or f"a local cluster of {args.workers or 'one worker per core'}"
    n_runs = len(plan.seeds) * len(plan.modes) * len(plan.sweep_values)
    print(f"{plan.scenario.name}: {len(plan.seeds)} seeds x {', '.join(plan.modes)}"
          f"{f' x {key} in {texts}' if key else ''} = {n_runs} replays on {where}; results in {plan.out}", flush=True)
    with open_client(args.scheduler, args.workers) as client:
        outcome = run_plan(plan, client, progress=not args.quiet)
    print_summary(outcome, key)
    return 1 if any("error" in s for s in outcome.summaries) else 0


def _f(x, fmt=".2f") -> str:
    return "-" if x is None else format(x, fmt)


def print_summary(outcome, key: str | None) -> None:
    agg = outcome.aggregate
    print(f"{agg['runs']} runs ({agg['failed']} failed) in {outcome.wall_s:.1f} s on {outcome.workers} workers")
    for g in agg["groups"]:
        name = g["mode"] + (f" {key}={g[key]}" if key else "")
        if not g.get("succeeded"):
            print(f"{name}: every run failed, e.g. {g['failed'][0]['error']}")
            continue
        n, e = g["nees9"], g["errors"]
        print(f"{name}: {g['succeeded']} runs; 9-state NEES averaged over runs: time average "
              f"{_f(n['time_averaged'])} (expected {n['dof']}), {100 * n['fraction_inside']:.1f} % of {n['epochs']} "
              f"epochs inside the {100 * (1 - n['alpha']):.0f} % band {_f(n['band_all_runs'][0])}.."
              f"{_f(n['band_all_runs'][1])} ({100 * n['fraction_below']:.1f} % below, "
              f"{100 * n['fraction_above']:.1f} % above); horizontal RMS {_f(e['horizontal_rms_m'].get('mean'))} m "
              f"(runs {_f(e['horizontal_rms_m'].get('min'))}..{_f(e['horizontal_rms_m'].get('max'))}), vertical "
              f"{_f(e['vertical_rms_m'].get('mean'))} m")
        for kind, s in g["nis"].items():
            print(f"    NIS {kind}: {s['accepted']} updates, mean per dof {_f(s['mean_per_dof'])} (band "
                  f"{_f(s['band_mean_per_dof'][0])}..{_f(s['band_mean_per_dof'][1])}), "
                  f"{100 * s['fraction_inside']:.1f} % of {s['cells']} cells inside their band")
        for f in g["failed"]:
            print(f"    seed {f['seed']} FAILED: {f['error']}", file=sys.stderr)
    print("files: " + ", ".join(str(p) for p in outcome.files))
