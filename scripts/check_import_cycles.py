#!/usr/bin/env python3
"""Fails when two files under src/ import each other, directly or through a chain, or when two sibling
modules (files or folders) do: `figures/overlap.rs -> report/mod.rs` and `report/mod.rs -> figures/mod.rs`
make `figures` and `report` depend on each other even though no single file chain closes a loop.

Builds the file-level graph of `use` items and inline `crate::`/`super::` paths (a path resolves to the
deepest module file that exists) and prints every strongly connected component of more than one file.
A module using its own descendants (`projection::run`, `self::select::x`) is not an edge: declaring
and re-exporting child modules is how Rust composes a folder, not a cycle. `super::` inside an inline
`mod tests { … }` refers to the file itself. Exit status 1 when a cycle exists.
Usage: python3 scripts/check_import_cycles.py [src]"""
import os, re, sys
root = sys.argv[1] if len(sys.argv) > 1 else 'src'
files = {}
for d, _, fs in os.walk(root):
    for f in fs:
        if f.endswith('.rs'):
            p = os.path.join(d, f)
            rel = os.path.relpath(p, root)[:-3].split(os.sep)
            if rel[-1] == 'mod': rel = rel[:-1]
            if rel == ['lib'] or rel == ['main']: rel = []
            files[tuple(rel)] = p
mods = set(files)
def resolve(path):
    # deepest existing module prefix
    for n in range(len(path), -1, -1):
        if tuple(path[:n]) in mods: return tuple(path[:n])
    return ()
def expand_use(s):
    # expand one level of braces: a::{b, c::d} -> a::b, a::c::d (nested handled recursively)
    m = re.search(r'\{', s)
    if not m: return [s]
    end = len(s) - 1
    pre = s[:m.start()]
    depth = 0
    for i in range(m.start(), len(s)):
        if s[i] == '{': depth += 1
        elif s[i] == '}':
            depth -= 1
            if depth == 0: end = i; break
    inner = s[m.start()+1:end]; post = s[end+1:]
    parts, depth, cur = [], 0, ''
    for ch in inner:
        if ch == ',' and depth == 0: parts.append(cur); cur = ''; continue
        if ch == '{': depth += 1
        if ch == '}': depth -= 1
        cur += ch
    parts.append(cur)
    out = []
    for p in parts:
        p = p.strip()
        if p: out += expand_use(pre + p + post)
    return out
def inline_modules(src):
    """(start, end, name) of each inline `mod name { ... }` block (e.g. `mod tests`)."""
    spans = []
    for mm in re.finditer(r'\bmod\s+(\w+)\s*\{', src):
        depth = 0
        for i in range(mm.end() - 1, len(src)):
            if src[i] == '{': depth += 1
            elif src[i] == '}':
                depth -= 1
                if depth == 0: spans.append((mm.start(), i, mm.group(1))); break
    return spans
graph = {m: set() for m in mods}
for m, p in files.items():
    src = open(p).read()
    src = re.sub(r'//[^\n]*', '', src)
    spans = inline_modules(src)
    occurrences = []
    for u in re.finditer(r'^\s*(?:pub(?:\([^)]*\))?\s+)?use\s+([^;]+);', src, re.M):
        occurrences += [(u.start(), q) for q in expand_use(re.sub(r'\s+', '', u.group(1)))]
    occurrences += [(x.start(), x.group(1)) for x in re.finditer(r'\b((?:crate|super)(?:::\w+)+)', src)]
    for pos, q in occurrences:
        segs = [s for s in q.split('::') if s]
        if not segs: continue
        # the module this occurrence sits in: the file's, or an inline module inside it
        here = list(m) + [n for a, b, n in spans if a < pos < b]
        if segs[0] == 'crate': base, rest = [], segs[1:]
        elif segs[0] in ('super', 'self'):
            base, rest = here, segs
            while rest and rest[0] in ('super', 'self'):
                if rest[0] == 'super': base = base[:-1]
                rest = rest[1:]
        else: continue
        t = resolve(base + rest)
        # a module using its own descendants (declaring, re-exporting children) is composition, not a cycle
        if t != () and t[:len(m)] != m:
            graph[m].add(t)
def name(m): return '/'.join(m) or 'lib'
sys.setrecursionlimit(10000)
index, low, stack, on, sccs = {}, {}, [], set(), []
c = [0]
def strong(v):
    index[v] = low[v] = c[0]; c[0] += 1; stack.append(v); on.add(v)
    for w in graph[v]:
        if w not in index: strong(w); low[v] = min(low[v], low[w])
        elif w in on: low[v] = min(low[v], index[w])
    if low[v] == index[v]:
        comp = []
        while True:
            w = stack.pop(); on.discard(w); comp.append(w)
            if w == v: break
        if len(comp) > 1: sccs.append(comp)
for v in graph:
    if v not in index: strong(v)
file_sccs, files_graph = list(sccs), graph
# Sibling level: an edge a -> b lifts to the children of their deepest common ancestor that contain them.
siblings = {}
for a, targets in graph.items():
    for b in targets:
        n = 0
        while n < min(len(a), len(b)) and a[n] == b[n]: n += 1
        if n < len(a) and n < len(b):
            siblings.setdefault(a[:n + 1], set()).add(b[:n + 1])
            siblings.setdefault(b[:n + 1], set())
graph, sccs = siblings, []
index.clear(); low.clear(); stack.clear(); on.clear()
for v in graph:
    if v not in index: strong(v)
folder_sccs = [comp for comp in sccs if not any(set(comp) <= set(f) for f in file_sccs)]
for comp in folder_sccs:
    print('cycle between sibling modules:', ', '.join(sorted(name(x) for x in comp)))
    for a in comp:
        for b in sorted(graph[a]):
            if b in comp: print('   ', name(a), '->', name(b))
graph, sccs = files_graph, file_sccs
for comp in sccs:
    print('cycle:', ', '.join(sorted(name(x) for x in comp)))
    for a in comp:
        for b in graph[a]:
            if b in comp: print('   ', name(a), '->', name(b))
print(f'import cycles between files under {root}: {len(sccs)}; between sibling modules: {len(folder_sccs)}')
sys.exit(1 if sccs or folder_sccs else 0)
