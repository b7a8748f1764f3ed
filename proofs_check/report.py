"""Tables, report.md and the JSON report of ``sern check``."""

from __future__ import annotations

import math

from . import framework as fw


def _ok(r) -> str:
    return "yes" if r.ok else "**NO**"


def table(results) -> str:
    """Plain-text table: name, expected, verdict, as expected, headline (statistic vs bound)."""
    rows = [("check", "expected", "verdict", "ok", "wall s", "worst cell: statistic [CI] vs bound")]
    for r in results:
        rows.append((r.name, r.expected, r.verdict, "yes" if r.ok else "NO",
                     f"{r.wall_s:.1f}", r.headline))
    w = [max(len(row[i]) for row in rows) for i in range(5)]
    lines = []
    for i, row in enumerate(rows):
        lines.append("  ".join(row[j].ljust(w[j]) for j in range(5)) + "  " + row[5])
        if i == 0:
            lines.append("-" * (sum(w) + 10 + 40))
    return "\n".join(lines)


def _jsonable(x):
    if isinstance(x, float) and not math.isfinite(x):
        return str(x)
    return x


def build_json(results, args, total_s, command) -> dict:
    from sern_jax.infra import io

    options = dict(quick=args.quick, only=args.only, seeds=args.seeds, alpha=args.alpha,
                   seed=args.seed, wrong_bounds=args.wrong_bounds)
    checks = []
    for r in results:
        d = r.to_json()
        d["cells"] = [{k: _jsonable(v) for k, v in c.items()} for c in d["cells"]]
        checks.append(d)
    return {
        "command": command,
        "options": options,
        "metadata": io.run_metadata(),
        "wall_s": total_s,
        "all_as_expected": all(r.ok for r in results),
        "summary": [dict(name=r.name, expected=r.expected, verdict=r.verdict, ok=r.ok,
                         headline=r.headline, wall_s=r.wall_s) for r in results],
        "checks": checks,
    }


def _machine(meta: dict) -> str:
    host = meta.get("host", {})
    jx = meta.get("jax", {})
    ver = meta.get("versions", {}).get("jax", "?")
    return (f"{host.get('machine', '?')} {host.get('cpu_count', '?')} CPUs, jax {ver} on "
            f"{jx.get('backend', '?')} {jx.get('devices', '')}")


def build_markdown(results, doc) -> str:
    md = ["# sern check report", "",
          f"Command: `{doc['command']}`  ",
          f"Wall time: {doc['wall_s']:.0f} s; machine: {_machine(doc['metadata'])}; "
          f"git {doc['metadata'].get('git_commit', '?')}  ",
          f"All verdicts as expected: **{doc['all_as_expected']}**", "",
          "Verdicts: PASS (no cell rejected the claim, with power), FAIL (rejected: Holm at "
          f"family level {doc['options']['alpha']}, or an exact violation), UNINFORMATIVE (no "
          "power), VACUOUS (bound ≥ trivial bound, or cannot be exceeded by construction). "
          "Expected HOLDS ⇒ must not FAIL; expected FAILS (negative control / counterexample) ⇒ "
          "must FAIL.", "",
          "| check | expected | verdict | as expected | worst cell: statistic [CI] vs bound |",
          "|---|---|---|---|---|"]
    for r in results:
        md.append(f"| `{r.name}` | {r.expected} | {r.verdict} | {_ok(r)} | {r.headline} |")
    md.append("")
    for r in results:
        md += [f"## `{r.name}` — {r.verdict} (expected {r.expected})", "",
               f"* **Claim:** {r.claim}",
               f"* **Configuration:** {r.configuration} (seeds: {r.seeds or 'n/a'})",
               f"* **Statistic:** {r.statistic}",
               f"* **Bound:** {r.bound}",
               f"* **Family size:** {r.family_size} cells; **power:** {r.power or '–'}"]
        if r.by_construction:
            md.append(f"* **Cannot fail by construction:** {r.by_construction}")
        if r.notes:
            md.append(f"* **Notes:** {r.notes}")
        md.append(f"* **Deliberately wrong bound used by the self-test:** {r.mutation}")
        md.append(f"* Wall time {r.wall_s:.1f} s")
        md += ["", "| cell | statistic | CI | bound | p | verdict | expect | note |",
               "|---|---|---|---|---|---|---|---|"]
        for c in r.cells:
            ci = "exact" if c.exact else f"[{fw.fmt(c.lower)}, {fw.fmt(c.upper)}]"
            op = {"le": "≤", "ge": "≥", "eq": "="}[c.direction]
            tag = " (reported only)" if c.info_only else ""
            md.append(f"| {c.label}{tag} | {fw.fmt(c.statistic)} | {ci} | {op} {fw.fmt(c.bound)} "
                      f"| {fw.fmt(c.pvalue)} | {c.verdict} | {c.expect or ''} | {c.note} |")
        md.append("")
    return "\n".join(md) + "\n"
