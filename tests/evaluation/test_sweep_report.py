from lastmile.evaluation.sweep_report import write_sweep_report


def _row(name: str, fault: dict | None) -> dict:
    ok = fault is None or fault["ok"]
    return {
        "name": name,
        "group": "faults",
        "weather": "clear",
        "faults": [fault["fault"]] if fault else [],
        "passed": ok,
        "checks": {"fault_answered": {"ok": ok, "detail": "x"}},
        "incidents": [],
        "scenario_file": f"scenarios/{name}.toml",
        "recording": None,
        "fault_response": [fault] if fault else [],
    }


def _fault(after: float | None, ok: bool) -> dict:
    return {
        "fault": "dropout:radar_front",
        "expected_level": "MINIMAL_RISK_MANOEUVRE",
        "bound_s": 0.15,
        "detected_after_s": after,
        "first_level": None if after is None else "SPEED_LIMIT",
        "max_level_10s": "MINIMAL_RISK_MANOEUVRE" if after is not None else "NONE",
        "ok": ok,
    }


def test_report_tabulates_fault_response_per_kind(tmp_path):
    rows = [_row("a", _fault(0.09, True)), _row("b", _fault(0.12, True)), _row("c", _fault(None, False))]
    rows.append(_row("d", None))
    summary = {"scenarios": 4, "passed": 3, "failed": 1, "collisions_total": 0, "collisions_at_fault": 0}
    text = write_sweep_report({**summary, "rows": rows}, tmp_path, "t").read_text()
    assert "## Fault response" in text
    line = next(x for x in text.splitlines() if x.startswith("| dropout:radar_front"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[1:4] == ["3", "2", "0.12 / 0.12 (1 never)"]
    assert cells[5] == "MINIMAL_RISK_MANOEUVRE" and cells[6] == "MINIMAL_RISK_MANOEUVRE, NONE"


def test_an_interrupted_sweep_says_so_and_never_passes_a_cut_case(tmp_path):
    cut = {**_row("b", None), "interrupted": True}
    rows = [_row("a", None), cut]
    summary = {"scenarios": 2, "passed": 1, "failed": 1, "collisions_total": 0, "collisions_at_fault": 0}
    summary |= {"interrupted": True, "not_run": ["c"]}
    text = write_sweep_report({**summary, "rows": rows}, tmp_path, "t").read_text()
    assert "**Interrupted** (Ctrl-C or SIGTERM): 1 scenarios stopped early" in text
    assert "1 not run: `c`." in text
    assert "| `b` | clear | - | interrupted |" in text
    assert "| faults | 2 | 1 | 1 |" in text
