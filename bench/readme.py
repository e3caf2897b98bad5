"""README.md's PERFORMANCE table, written from a bench report: its numbers are never typed in.

:func:`write` replaces what lies between the ``<!-- bench:start -->`` and ``<!-- bench:end -->``
markers of README.md with a line saying when, where and under what load the run was made, and
the table of :func:`bench.__main__.rows` (the rows ``python -m bench`` prints), as markdown.
"""

from __future__ import annotations

import datetime
import re

START, END = "<!-- bench:start -->", "<!-- bench:end -->"


def table(report: dict) -> str:
    from bench.__main__ import rows

    m, c, t = report["machine"], report["ceiling"], report["tracer"]
    when = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    argv = " ".join(report.get("argv", []))
    command = f"`make bench BENCH_ARGS='{argv}'` (`python -m bench {argv}`)" if argv else "`make bench`"
    head = (f"Last run: {command}, {when}, {m['cpus']} CPUs ({m['platform']}, Python {m['python']}), load average "
            f"{report['load_start']:.1f} at the start and {report['load_end']:.1f} at the end (other work on the "
            f"machine: compare the CPU-time ratios, not the wall times, across runs). Default torso "
            f"({c['triangles']} triangles), capsule `small_intestine_1`, the {t['receivers']} sensor sites, "
            f"`max_interactions` {t['max_interactions']}, {t['rays']:.0e} rays, 402 MHz.")
    lines = [head, "", "| measure | value | target |", "|---|---|---|"]
    for name, value, target in rows(report):
        lines.append(f"| {name.strip()} | {value} | {target.removeprefix('target ') or '—'} |")
    return "\n".join(lines)


def write(report: dict, path: str) -> None:
    """Replace the table between the markers of ``path`` (README.md); raise if they are missing."""
    with open(path) as fh:
        text = fh.read()
    pattern = re.compile(re.escape(START) + r".*?" + re.escape(END), flags=re.S)
    if not pattern.search(text):
        raise ValueError(f"{path} has no {START} ... {END} markers around its PERFORMANCE table")
    new = pattern.sub(lambda _m: f"{START}\n{table(report)}\n{END}", text, count=1)
    with open(path, "w") as fh:
        fh.write(new)
