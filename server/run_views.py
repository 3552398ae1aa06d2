"""What the Runs tab shows, as pure functions of RunInfo: filter, groups, the table (Markdown),
legend labels that tell runs apart, and the difference between two configs.

Nothing here depends on the clock: the table changes only when a run changes, so an idle
dashboard sends nothing (an "updated N s ago" column would re-send the table every second).
"""

from __future__ import annotations

import time
from typing import Any, Sequence

import yaml

from detach.runfolder.files import parse_yaml
from server.markup import md_code, md_text
from server.run_index import RunInfo

GROUP_BY = ("nothing", "task", "model", "seed", "sweep cell", "state")
"""What the runs table can be grouped by."""


def short_id(info: RunInfo) -> str:
    """The run id without the '-<task>-<model>-s<seed>' that the table's columns repeat."""
    tail = f"-{info.task}-{info.model}-s{info.seed}"
    stamp, found, suffix = info.run_id.partition(tail)
    return stamp + suffix if found and stamp else info.run_id


def clock(t: float | None) -> str:
    """A Unix time as 'mm-dd HH:MM' (local time); '-' if unknown."""
    if not isinstance(t, (int, float)):
        return "-"
    return time.strftime("%m-%d %H:%M", time.localtime(t))


def search_text(info: RunInfo) -> str:
    """What the filter box matches against."""
    return " ".join(str(v) for v in (info.run_id, info.task, info.model, f"s{info.seed}",
                                     info.cell or "", info.shown_state)).lower()


def filter_runs(infos: Sequence[RunInfo], text: str) -> list[RunInfo]:
    """Runs whose id, task, model, 's<seed>', sweep cell or state contain every word."""
    words = text.lower().split()
    return [i for i in infos if all(w in search_text(i) for w in words)]


def group_key(info: RunInfo, by: str) -> str:
    if by == "task":
        return info.task
    if by == "model":
        return info.model
    if by == "seed":
        return f"seed {info.seed}"
    if by == "sweep cell":
        return info.cell.rsplit("/", 1)[0] if info.cell else "(not in a sweep)"
    if by == "state":
        return info.shown_state
    return ""


def group_runs(infos: Sequence[RunInfo], by: str) -> dict[str, list[RunInfo]]:
    """Runs by task / model / seed / sweep cell (its seeds together) / state, in order."""
    if by not in GROUP_BY:
        raise ValueError(f"unknown grouping {by!r}; expected one of {', '.join(GROUP_BY)}")
    groups: dict[str, list[RunInfo]] = {}
    for info in infos:
        groups.setdefault(group_key(info, by), []).append(info)
    return dict(sorted(groups.items()))


def runs_table(infos: Sequence[RunInfo], selected: Sequence[str] = (), by: str = "nothing",
               total: int | None = None) -> str:
    """The runs tab: one row per run folder (newest last), grouped if asked, the runs chosen
    for comparison ticked, then the reasons of failed and unreadable runs."""
    if not infos:
        return ("*No run folders match the filter.*" if total else
                "*No run folders yet.* New runs appear here as soon as they are created.")
    chosen = set(selected)
    parts = []
    if total is not None and total != len(infos):
        parts.append(f"{len(infos)} of {total} runs match the filter.\n")
    for group, members in group_runs(infos, by).items():
        if by != "nothing":
            parts.append(f"**{by} {md_text(group)}** ({len(members)} run"
                         f"{'s' if len(members) != 1 else ''})\n")
        lines = ["| | run | task | model | seed | state | iter | LH SR | updated |",
                 "| :-: | --- | --- | --- | --: | --- | --: | --: | --- |"]
        for r in members:
            state = f"**{r.shown_state}**" if r.unreadable or r.state == "failed" else r.state
            lines.append(" | ".join([
                "| " + ("✓" if r.run_id in chosen else ""), f"{md_code(short_id(r))}", md_text(r.task),
                md_text(r.model), "-" if r.seed is None else str(r.seed), state,
                "-" if r.iteration is None else str(r.iteration),
                "-" if r.lh_sr is None else f"{r.lh_sr:.2f}", clock(r.updated)]) + " |")
        parts.append("\n".join(lines) + "\n")
    notes = [f"- {md_code(r.run_id)} ({r.state}): " + "; ".join(md_text(p) for p in r.problems)
             for r in infos if r.unreadable]
    notes += [f"- {md_code(r.run_id)} {r.state}: {md_text(r.error)}" for r in infos
              if r.error and not r.unreadable]
    if notes:
        parts.append("**Problems**\n\n" + "\n".join(notes) + "\n")
    return "\n".join(parts)


def run_label(info: RunInfo | None, run_id: str) -> str:
    """Short legend label: model/task/seed, which is what runs are compared by."""
    if info is None or info.task == "?":
        return run_id
    return f"{info.model} {info.task} s{info.seed}"


def run_labels(infos: Sequence[RunInfo]) -> dict[str, str]:
    """Legend labels that are unique among `infos`: 'model task s<seed>', and for runs that
    share it, their sweep cell or else the time stamp of their folder."""
    base = {i.run_id: run_label(i, i.run_id) for i in infos}
    counts: dict[str, int] = {}
    for label in base.values():
        counts[label] = counts.get(label, 0) + 1
    labels = {}
    for i in infos:
        label = base[i.run_id]
        if counts[label] > 1:
            stamp = short_id(i) if i.task != "?" else i.run_id
            label = f"{label} ({i.cell.split('/', 1)[0] + ' ' if i.cell else ''}{stamp})"
        labels[i.run_id] = label
    seen: dict[str, int] = {}
    for run_id, label in labels.items():  # identical folders' copies: number them
        seen[label] = seen.get(label, 0) + 1
        if seen[label] > 1:
            labels[run_id] = f"{label} #{seen[label]}"
    return labels


def status_markdown(info: RunInfo) -> str:
    """The status of one run, with its failure reason and the problems of its folder."""
    lines = [f"**{md_text(info.run_id)}**", "",
             f"- state: **{info.shown_state}**" + (f" (sweep cell {md_code(info.cell)})"
                                                  if info.cell else ""),
             f"- iteration: {info.iteration if info.iteration is not None else '-'}",
             f"- started {clock(info.started)}, updated {clock(info.updated)}",
             f"- LH success on its task: {'-' if info.lh_sr is None else f'{info.lh_sr:.2f}'}"]
    if info.error:
        lines.append(f"- **error:** {md_text(info.error)}")
    lines += [f"- **problem:** {md_text(p)}" for p in info.problems]
    return "\n".join(lines)


def flatten(data: Any, prefix: str = "") -> dict[str, Any]:
    """A nested mapping as dotted keys (lists are values, as the override syntax sees them)."""
    if not isinstance(data, dict):
        return {prefix: data} if prefix else {}
    out: dict[str, Any] = {}
    for k, v in data.items():
        key = f"{prefix}.{k}" if prefix else str(k)
        if isinstance(v, dict) and v:
            out.update(flatten(v, key))
        else:
            out[key] = v
    return out


def config_diff(a_text: str, b_text: str) -> list[tuple[str, Any, Any]]:
    """(key, value in a, value in b) of every dotted key whose values differ; a key missing
    on one side has the value None there."""
    a = flatten(parse_yaml(a_text, "A's config.yaml") or {})  # the CLI's value limit: no alias bomb
    b = flatten(parse_yaml(b_text, "B's config.yaml") or {})
    return [(k, a.get(k), b.get(k)) for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]


def diff_markdown(a: str, b: str, rows: Sequence[tuple[str, Any, Any]]) -> str:
    if not rows:
        return f"{md_code(a)} and {md_code(b)} have the same configuration."
    lines = [f"{len(rows)} key(s) differ.", "", "| key | A | B |", "| --- | --- | --- |"]
    lines += [f"| {md_code(k)} | {md_text(_short_value(va))} | {md_text(_short_value(vb))} |"
              for k, va, vb in rows]
    return "\n".join(lines)


def _short_value(v: Any, limit: int = 60) -> str:
    text = "(absent)" if v is None else yaml.safe_dump(v, default_flow_style=True,
                                                       width=10**6).strip()
    text = text.removesuffix("\n...").strip()
    return text if len(text) <= limit else text[: limit - 1] + "…"
