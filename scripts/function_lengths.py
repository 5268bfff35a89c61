#!/usr/bin/env python3
"""Function lengths in src/ (issue 26: no function longer than 120 lines).

A brace-matching scan, no compiler: comments, string and character literals and preprocessor
lines are blanked, then every top-level '{' (one not inside a function body) whose header ends
like a function's -- ')' followed by qualifiers (const, override, noexcept, final, mutable,
'-> type'), or a constructor's initialiser list -- opens a function; its length is the line of
its closing '}' minus the line where its header starts, plus one. Lambdas and local classes count
towards the function that holds them; a lambda at namespace scope counts as a function.

    python3 scripts/function_lengths.py                  # every function over 120 lines, longest first
    python3 scripts/function_lengths.py --limit 100      # another limit
    python3 scripts/function_lengths.py --top 20         # the 20 longest, whatever their length
    python3 scripts/function_lengths.py --check scripts/function_lengths_allowed.txt
        # exit 1 when a function over the limit is not listed in the file (lines "path name"),
        # or when a listed one is now within the limit (so the list only shrinks)
"""
import os
import re
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
QUALIFIERS = re.compile(r"\)\s*(?:(?:const|override|noexcept|final|mutable|volatile|&|&&)\s*|noexcept\s*\([^()]*\)\s*)*"
                        r"(?:->\s*[\w:<>,\s\*&]+)?\s*$")
CONTROL = re.compile(r"\b(if|for|while|switch|catch|do|else|return)\s*$")


def blank(text):
    """Comments, literals and preprocessor lines replaced by spaces (newlines kept)."""
    out, i, n = [], 0, len(text)
    line_start = True
    while i < n:
        c = text[i]
        if line_start and c == "#" :
            j = i
            while j < n:  # a preprocessor line, with its continuations
                k = text.find("\n", j)
                if k < 0:
                    k = n
                if k > 0 and text[k - 1] == "\\":
                    j = k + 1
                    continue
                break
            out.append(re.sub(r"[^\n]", " ", text[i:k]))
            i = k
            continue
        if c in " \t":
            out.append(c)
            i += 1
            continue
        line_start = c == "\n"
        if text.startswith("//", i):
            k = text.find("\n", i)
            k = n if k < 0 else k
            out.append(" " * (k - i))
            i = k
        elif text.startswith("/*", i):
            k = text.find("*/", i + 2)
            k = n if k < 0 else k + 2
            out.append(re.sub(r"[^\n]", " ", text[i:k]))
            i = k
        elif c == "R" and text.startswith('R"', i) and (i == 0 or not (text[i - 1].isalnum() or text[i - 1] == "_")):
            m = re.match(r'R"([^(\s]*)\(', text[i:])
            if not m:
                out.append(c)
                i += 1
                continue
            end = text.find(")" + m.group(1) + '"', i)
            k = n if end < 0 else end + len(m.group(1)) + 2
            out.append('""' + re.sub(r"[^\n]", " ", text[i + 2:k]))
            i = k
        elif c in "\"'":
            if c == "'" and i > 0 and text[i - 1].isalnum() and i + 1 < n and text[i + 1].isalnum():
                out.append(" ")  # digit separator 1'000
                i += 1
                continue
            j = i + 1
            while j < n and text[j] != c:
                j += 2 if text[j] == "\\" else 1
            out.append(c + re.sub(r"[^\n]", " ", text[i + 1:j]) + c)
            i = j + 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


def name_of(header):
    h = re.sub(r"\s+", " ", header).strip()
    depth, end = 0, None
    for k in range(len(h) - 1, -1, -1):  # the parameter list that closes the declarator
        if h[k] == ")":
            depth += 1
        elif h[k] == "(":
            depth -= 1
            if depth == 0:
                end = k
                if not re.search(r"\)\s*:\s*[\w:]", h[:k + 1]) or True:
                    pass
    # the first '(' at depth 0 that follows a name: the function's own
    depth = 0
    for k, ch in enumerate(h):
        if ch == "(" and depth == 0:
            m = re.search(r"([\w:~]+(?:operator\s*\S+?)?|\[[^\]]*\])\s*$", h[:k])
            if m:
                return m.group(1)
        if ch in "<([":
            depth += ch != "<"
        elif ch in ">)]":
            depth -= ch != ">"
    return h[:60]


def functions(path):
    text = blank(open(path, encoding="utf-8", errors="replace").read())
    res = []
    stack = []  # per open brace: "fn" or "box" (namespace, class, initialiser...)
    header_start = 0
    i, n = 0, len(text)
    fn_depth = None
    while i < n:
        c = text[i]
        if c == "{":
            if fn_depth is not None:
                stack.append("in")
            else:
                header = text[header_start:i]
                h = header.strip()
                ctor = re.search(r"\)\s*:\s*[\w:]", h) is not None
                if "(" in h and not CONTROL.search(h) and (QUALIFIERS.search(h) or (ctor and h.endswith(("}", ")")))):
                    fn_depth = len(stack)
                    start = header_start + len(header) - len(header.lstrip())
                    stack.append(("fn", start))
                elif "(" in h and ctor:
                    # a brace initialiser in a constructor's list: skip it, the header goes on
                    j, d = i, 0
                    while j < n:
                        d += text[j] == "{"
                        d -= text[j] == "}"
                        if d == 0:
                            break
                        j += 1
                    i = j + 1
                    continue
                else:
                    stack.append("box")
                    header_start = i + 1
        elif c == "}":
            top = stack.pop() if stack else "box"
            if isinstance(top, tuple):
                start = top[1]
                first = text.count("\n", 0, start) + 1
                last = text.count("\n", 0, i) + 1
                res.append((last - first + 1, first, name_of(text[start:text.index("{", start)])))
                fn_depth = None
                header_start = i + 1
            elif fn_depth is None:
                header_start = i + 1
        elif c == ";" and fn_depth is None:
            header_start = i + 1
        i += 1
    return res


def scan():
    out = []
    for dirpath, _, files in os.walk(os.path.join(ROOT, "src")):
        for fn in sorted(files):
            if fn.endswith((".cpp", ".h", ".hpp")):
                path = os.path.join(dirpath, fn)
                rel = os.path.relpath(path, ROOT)
                for length, line, name in functions(path):
                    out.append((length, rel, line, name))
    out.sort(key=lambda t: (-t[0], t[1], t[2]))
    return out


def main(argv):
    limit, top, check = 120, None, None
    args = list(argv)
    while args:
        a = args.pop(0)
        if a == "--limit":
            limit = int(args.pop(0))
        elif a == "--top":
            top = int(args.pop(0))
        elif a == "--check":
            check = args.pop(0)
        else:
            print(__doc__)
            return 2
    rows = scan()
    shown = rows[:top] if top else [r for r in rows if r[0] > limit]
    for length, rel, line, name in shown:
        print(f"{length:5d}  {rel}:{line}  {name}")
    over = [r for r in rows if r[0] > limit]
    print(f"{len(over)} functions over {limit} lines ({len(rows)} functions in src/)")
    if check:
        allowed = set()
        with open(os.path.join(ROOT, check) if not os.path.isabs(check) else check) as f:
            for ln in f:
                ln = ln.split("#", 1)[0].strip()
                if ln:
                    path, name = ln.split(None, 1)
                    allowed.add((path, name.strip()))
        found = {(r[1], r[3]) for r in over}
        new = sorted(found - allowed)
        gone = sorted(allowed - found)
        for p, nm in new:
            print(f"NEW over {limit} lines: {p} {nm}")
        for p, nm in gone:
            print(f"now within {limit} lines, remove from {check}: {p} {nm}")
        return 1 if new or gone else 0
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
