#!/usr/bin/env python3
"""Writes the agents benchmark's timer table from ../shared/limit/params.json.

Usage: limit_agents_timers.py [PARAMS.json] [OUT.csv]
(defaults: ../shared/limit/params.json, benches/models/limit_agents_timers.csv)

The limit's reference (`../shared/limit/src/agents.rs`) replays the pre-drawn
values `agents.draws` of params.json: row n is each agent's n-th timer value
(row 0 the initial timers). This copies them verbatim, one row per line, in
Python's shortest round-trip form (the JSON text's digits), so hybsim reads the
same doubles. `tests/it/tables.rs` checks the file against params.json.
"""
import json
import sys

params = sys.argv[1] if len(sys.argv) > 1 else "../shared/limit/params.json"
out = sys.argv[2] if len(sys.argv) > 2 else "benches/models/limit_agents_timers.csv"
draws = json.load(open(params))["agents"]["draws"]
with open(out, "w") as f:
    f.write("# ../shared/limit/params.json agents.draws: row n = each agent's n-th timer value\n")
    f.write("agent1,agent2,agent3\n")
    for row in draws:
        f.write(",".join(repr(float(v)) for v in row) + "\n")
