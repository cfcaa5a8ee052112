"""Summary, Markdown and figure of a soak run (benchmarks/soak.py): pure functions of its
results dictionary (``soak.json``), so a saved run can be summarised again:

    python benchmarks/soak_report.py soak_out/soak.json      # prints the Markdown
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys

import numpy as np

PERCENTILES = (50, 90, 99)


def machine() -> dict:
    """Cores, CPU model, memory, Python and rclpy versions of this machine."""
    info = {"cores": os.cpu_count(), "python": platform.python_version(),
            "kernel": platform.release(), "cpu": platform.processor() or "?"}
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    info["cpu"] = line.split(":", 1)[1].strip()
                    break
        with open("/proc/meminfo") as f:
            info["mem_gb"] = round(int(f.readline().split()[1]) / 2**20, 1)
    except OSError:
        pass
    try:
        from importlib.metadata import version
        info["rclpy"] = version("rclpy")
    except Exception:  # noqa: BLE001 - informational only
        info["rclpy"] = "?"
    info["rmw"] = os.environ.get("RMW_IMPLEMENTATION", "default")
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    try:
        head = subprocess.run(["git", "-C", root, "rev-parse", "--short", "HEAD"],
                              capture_output=True, text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "-C", root, "status", "--porcelain", "--",
                                "rbc_registration"], capture_output=True, text=True,
                               timeout=10).stdout.strip()
        info["git"] = f"{head}{' + uncommitted changes in rbc_registration/' if dirty else ''}"
    except (OSError, subprocess.SubprocessError):
        info["git"] = "?"
    return info


def latency_stats(seconds: list[float]) -> dict:
    """calls, p50/p90/p99/max/mean [ms] of latencies in seconds."""
    ms = np.asarray(seconds, dtype=np.float64) * 1e3
    if ms.size == 0:
        return {"calls": 0}
    out = {"calls": int(ms.size), "mean_ms": float(ms.mean()), "max_ms": float(ms.max())}
    for p in PERCENTILES:
        out[f"p{p}_ms"] = float(np.percentile(ms, p))
    return out


def slope_per_hour(t: np.ndarray, y: np.ndarray) -> float:
    """Least-squares slope of ``y`` per hour (``t`` in seconds); NaN with < 3 points."""
    if len(t) < 3 or np.ptp(t) == 0:
        return float("nan")
    return float(np.polyfit(t, y, 1)[0] * 3600.0)


def latency_bins(results: dict, width: float) -> list[dict]:
    """Per time bin of ``width`` s: calls, p50, p99 and max latency [ms] over all clients."""
    t = np.concatenate([np.asarray(c.get("t", []), dtype=float) for c in _clients(results)])
    lat = np.concatenate([np.asarray(c.get("latency_s", []), dtype=float)
                          for c in _clients(results)]) * 1e3
    bins = []
    if t.size == 0:
        return bins
    edges = np.arange(0.0, t.max() + width, width)
    for lo in edges:
        sel = lat[(t >= lo) & (t < lo + width)]
        if sel.size:
            bins.append({"t": float(lo + width / 2), "calls": int(sel.size),
                         "p50_ms": float(np.percentile(sel, 50)),
                         "p99_ms": float(np.percentile(sel, 99)), "max_ms": float(sel.max())})
    return bins


def _clients(results: dict) -> list[dict]:
    return [v for k, v in sorted(results["children"].items()) if k.startswith("client")]


def summarise(results: dict) -> dict:
    """Latency percentiles, errors, memory slope, pair counts and the pass/fail checks."""
    settings, samples = results["settings"], results["samples"]
    clients = _clients(results)
    per_client = {f"client{c.get('index', k)}": latency_stats(c.get("latency_s", []))
                  for k, c in enumerate(clients)}
    overall = latency_stats([v for c in clients for v in c.get("latency_s", [])])
    errors = sum(c.get("n_errors", 0) for c in clients)
    kinds: dict[str, int] = {}
    for c in clients:
        for e in c.get("errors", []):
            kinds[e["kind"]] = kinds.get(e["kind"], 0) + 1
    fatal = {k: v["fatal"] for k, v in results["children"].items() if "fatal" in v}
    t = np.array([s["t"] for s in samples])
    rss = np.array([s["rss_mb"] for s in samples])
    n_meas = np.array([s["n_measurements"] for s in samples], dtype=float)
    mid = int(np.argmin(np.abs(t - settings["duration_s"] / 2))) if len(t) else 0
    half = t >= settings["duration_s"] / 2
    bytes_per = (float(np.polyfit(n_meas, rss, 1)[0] * 2**20)
                 if len(t) >= 3 and np.ptp(n_meas) > 0 else float("nan"))
    streamer = results["children"].get("streamer", {})
    published = streamer.get("published", -1)
    expected = int(np.ceil(settings["rate"] * settings["duration_s"] - 1e-9))
    if settings.get("max_pairs"):
        expected = min(expected, settings["max_pairs"])
    status = results["node_final_status"]
    journal = results["journal"]
    cpu = [s["node_cpu_pct"] for s in samples if "node_cpu_pct" in s]
    machine_cores = [s["machine_cpu_cores"] for s in samples if "machine_cpu_cores" in s]
    soak_cores = [s["soak_cpu_cores"] for s in samples if "soak_cpu_cores" in s]
    load = [s["load1"] for s in samples]
    summary = {
        "latency": {"overall": overall, **per_client},
        "calls_per_s": overall.get("calls", 0) / settings["duration_s"],
        "errors": errors + len(fatal), "error_kinds": kinds, "fatal": fatal,
        "rss_mb": {"before_stream": results["before"]["rss_mb"],
                   "start": float(rss[0]) if len(rss) else None,
                   "middle": float(rss[mid]) if len(rss) else None,
                   "end": float(rss[-1]) if len(rss) else None,
                   "final_after_drain": results["final"]["rss_mb"],
                   "peak_hwm": max([results["final"]["hwm_mb"], *rss.tolist()]),
                   "slope_mb_per_h": slope_per_hour(t, rss),
                   "slope_second_half_mb_per_h": slope_per_hour(t[half], rss[half]),
                   "bytes_per_accepted_measurement": bytes_per},
        "threads": [results["before"]["threads"], results["final"]["threads"]],
        "fds": [results["before"]["fds"], results["final"]["fds"]],
        "pairs": {"published": published, "expected": expected,
                  "accepted": status["n_measurements"], "rejected": status["n_rejected"],
                  "journal_measurements": journal["measurements"],
                  "journal_bytes": journal["bytes"],
                  "lost": published - status["n_measurements"],
                  "fiducials": status["n_fiducials"]},
        "stream": {k: streamer.get(k) for k in ("publish_retries", "lateness_max_s",
                                                "late_over_10ms", "all_acked")},
        "cpu": {"node_mean_pct": float(np.mean(cpu)) if cpu else float("nan"),
                "node_max_pct": float(np.max(cpu)) if cpu else float("nan"),
                "soak_mean_cores": float(np.mean(soak_cores)) if soak_cores else float("nan"),
                "machine_mean_cores": float(np.mean(machine_cores)) if machine_cores
                else float("nan"),
                "load1_min_mean_max": [min(load), float(np.mean(load)), max(load)] if load
                else []},
        "node_log_bytes": results.get("node_log_bytes"),
    }
    summary["cpu"]["others_mean_cores"] = (summary["cpu"]["machine_mean_cores"]
                                           - summary["cpu"]["soak_mean_cores"])
    summary["checks"] = {
        "no_errors": summary["errors"] == 0,
        "stream_complete": published == expected,
        "nothing_lost": published == status["n_measurements"] == journal["measurements"],
        "nothing_rejected": status["n_rejected"] == 0,
        "children_exit_0": all(v.get("exit_code") == 0 for v in results["children"].values()),
        "node_exit_0": results["node_exit_code"] == 0,
    }
    return summary


def _f(v, digits: int = 2) -> str:
    return "n/a" if v is None or v != v else f"{v:.{digits}f}"


def markdown(results: dict, summary: dict) -> str:
    """The run's summary as Markdown."""
    s, m = results["settings"], results["machine"]
    lat, rss, pairs, cpu = summary["latency"], summary["rss_mb"], summary["pairs"], summary["cpu"]
    stream = summary["stream"]
    think = "back-to-back" if s["think_s"] == 0 else f"{s['think_s'] * 1e3:g} ms think time"
    lines = [
        f"Soak: {s['duration_s']:g} s, {s['clients']} client processes calling "
        f"`~/correct_target` ({think}, timeout {s['call_timeout_s']:g} s), 1 streamer at "
        f"{s['rate']:g} FiducialPair/s"
        f"{' (only the first %d pairs)' % s['max_pairs'] if s.get('max_pairs') else ''}; "
        f"node with default parameters, journal in a temporary state_dir"
        + "".join(f", {k}={v}" for k, v in s.get("node_env", {}).items())
        + ". Machine: "
        f"{m['cores']} cores ({m['cpu']}), Python {m['python']}, rclpy {m['rclpy']}, "
        f"{m['rmw']}; code {m.get('git', '?')}.",
        "",
        "| client | calls | p50 ms | p90 ms | p99 ms | max ms |",
        "|---|---|---|---|---|---|",
    ]
    for name, st in lat.items():
        if st.get("calls"):
            lines.append(f"| {name} | {st['calls']} | {_f(st['p50_ms'], 3)} | "
                         f"{_f(st['p90_ms'], 3)} | {_f(st['p99_ms'], 3)} | {_f(st['max_ms'])} |")
    lines += [
        "",
        f"- calls: {lat['overall'].get('calls', 0)} ({summary['calls_per_s']:.0f}/s in all); "
        f"**errors: {summary['errors']}** {summary['error_kinds'] or ''}"
        f"{' fatal: ' + str(summary['fatal']) if summary['fatal'] else ''}",
        f"- pairs: published {pairs['published']} (schedule {pairs['expected']}), accepted "
        f"{pairs['accepted']}, journaled {pairs['journal_measurements']}, rejected "
        f"{pairs['rejected']}, **lost {pairs['lost']}**; {pairs['fiducials']} fiducials; "
        f"journal {pairs['journal_bytes'] / 1e6:.1f} MB",
        f"- streamer: {stream['publish_retries']} publish retries, most late "
        f"{_f((stream['lateness_max_s'] or 0.0) * 1e3, 1)} ms, "
        f"{stream['late_over_10ms']} sends > 10 ms late",
        f"- node RSS [MB]: {_f(rss['before_stream'], 1)} before the stream, "
        f"{_f(rss['start'], 1)} at start, {_f(rss['middle'], 1)} in the middle, "
        f"{_f(rss['end'], 1)} at the end (peak {_f(rss['peak_hwm'], 1)}); slope "
        f"{_f(rss['slope_mb_per_h'], 1)} MB/h over the run, "
        f"{_f(rss['slope_second_half_mb_per_h'], 1)} MB/h over the second half; "
        f"{_f(rss['bytes_per_accepted_measurement'], 0)} bytes per accepted measurement "
        f"(fit of RSS against the count)",
        f"- node threads {summary['threads'][0]} -> {summary['threads'][1]}, open files "
        f"{summary['fds'][0]} -> {summary['fds'][1]}, log {summary['node_log_bytes']} bytes",
        f"- CPU: node {_f(cpu['node_mean_pct'], 0)} % mean ({_f(cpu['node_max_pct'], 0)} % "
        f"max) of one core; all soak processes {_f(cpu['soak_mean_cores'])} cores; the "
        f"machine {_f(cpu['machine_mean_cores'])} of {m['cores']} cores, so others "
        f"{_f(cpu['others_mean_cores'])} cores; load average (1 min) "
        + (" / ".join(_f(v) for v in cpu["load1_min_mean_max"]) + " min / mean / max"
           if cpu["load1_min_mean_max"] else "n/a"),
        "- checks: " + ", ".join(f"{k} {'ok' if ok else 'FAILED'}"
                                 for k, ok in summary["checks"].items()),
        "",
    ]
    return "\n".join(lines)


def plot(results: dict, path: str) -> None:
    """RSS and accepted count, CPU, and latency (p50 / p99 / max per bin) over time."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    samples = results["samples"]
    t = np.array([s["t"] for s in samples])
    fig, axes = plt.subplots(3, 1, figsize=(9, 9), sharex=True)
    ax = axes[0]
    ax.plot(t, [s["rss_mb"] for s in samples], color="tab:blue")
    ax.set_ylabel("node RSS [MB]", color="tab:blue")
    twin = ax.twinx()
    twin.plot(t, [s["n_measurements"] / 1e3 for s in samples], color="tab:gray", ls="--")
    twin.set_ylabel("accepted pairs [thousands]", color="tab:gray")
    cpu = [(s["t"], s["node_cpu_pct"], s.get("machine_cpu_cores", np.nan) * 100)
           for s in samples if "node_cpu_pct" in s]
    if cpu:
        c = np.array(cpu)
        axes[1].plot(c[:, 0], c[:, 1], label="node [% of a core]")
        axes[1].plot(c[:, 0], c[:, 2], label="whole machine [% of a core]", alpha=0.6)
        axes[1].legend(loc="upper left", fontsize=8)
    axes[1].set_ylabel("CPU [%]")
    width = max(results["settings"]["sample_s"], results["settings"]["duration_s"] / 60)
    bins = latency_bins(results, width)
    if bins:
        bt = [b["t"] for b in bins]
        for key, label in (("p50_ms", "p50"), ("p99_ms", "p99"), ("max_ms", "max")):
            axes[2].plot(bt, [b[key] for b in bins], label=label)
        axes[2].set_yscale("log")
        axes[2].legend(loc="upper left", fontsize=8)
    axes[2].set_ylabel(f"correct_target latency [ms]\n(per {width:g} s, all clients)")
    axes[2].set_xlabel("time since start of the load [s]")
    s = results["settings"]
    fig.suptitle(f"registration_node soak: {s['clients']} clients, {s['rate']:g} pairs/s, "
                 f"{s['duration_s']:g} s")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    with open(sys.argv[1]) as f:
        data = json.load(f)
    print(markdown(data, data.get("summary") or summarise(data)))
