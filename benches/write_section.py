"""Replace the section between <!-- bench:NAME --> and <!-- /bench:NAME --> of BENCHMARKS.md with stdin.

Usage: ... | python3 benches/write_section.py NAME ["Heading for a new section"]
"""
import re
import sys

name = sys.argv[1]
heading = sys.argv[2] if len(sys.argv) > 2 else None
body = sys.stdin.read().rstrip("\n") + "\n"
start, end = f"<!-- bench:{name} -->", f"<!-- /bench:{name} -->"
try:
    old = open("BENCHMARKS.md").read()
except FileNotFoundError:
    old = ""
block = f"{start}\n{body}{end}"
if start in old:
    new = re.sub(re.escape(start) + ".*?" + re.escape(end), lambda m: block, old, flags=re.S)
else:
    sep = "\n" if old and not old.endswith("\n") else ""
    new = old + sep + (f"\n## {heading}\n\n" if heading else "") + block + "\n"
open("BENCHMARKS.md", "w").write(new)
