"""Held-out wordings of the benchmark's function expressions: each affordance said another way
(written before any result was seen), for `groupforward eval refer --expressions`.

Usage: python3 held_out_function_wordings.py DIR/expressions.csv held_out.jsonl template.jsonl
(DIR: an `eval refer` run; template.jsonl holds the same expressions in the benchmark's wording)."""
import csv, json, sys
PARA = {
    "sit on": "take a seat on",
    "put things on": "place items on",
    "eat at": "have dinner at",
    "work at": "do homework at",
    "put a computer on": "set a laptop on",
    "store things in": "keep my stuff in",
    "throw away rubbish": "dispose of garbage in",
    "wash hands": "rinse your hands at",
    "sleep on": "take a nap on",
    "lie down on": "stretch out on",
    "give light": "light up the room with",
    "keep books on": "shelve novels on",
    "use the toilet": "relieve yourself on",
    "keep food cold": "chill drinks in",
    "look at a screen": "watch videos on",
    "water": "give water to",
    "carry": "pack things in",
    "rest the head on": "lay your head on",
}
rows = list(csv.DictReader(open(sys.argv[1])))
out = open(sys.argv[2], "w")
template = open(sys.argv[3], "w")
n = 0
for r in rows:
    if r["relation"] != "function":
        continue
    text = r["expression"]
    for lead in ("all the things you can ", "the thing you can "):
        if text.startswith(lead):
            affordance = text[len(lead):]
            break
    else:
        continue
    targets = [int(t) for t in r["targets"].split()]
    para = lead + PARA[affordance]
    out.write(json.dumps({"scene": r["scene"], "text": para, "targets": targets, "relation": "function"}) + "\n")
    template.write(json.dumps({"scene": r["scene"], "text": text, "targets": targets, "relation": "function"}) + "\n")
    n += 1
print(n, "function expressions")
