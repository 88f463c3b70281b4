import sys
d = sys.argv[1]
chunk_ns = int(sys.argv[2]) if len(sys.argv) > 2 else 1_000_000
def load(p, n):
    r = {}
    for l in open(p):
        f = l.split()
        if len(f) == n: r[int(f[0])] = list(map(int, f))
    return r
loc = load(f"{d}/local.trace", 3); rep = load(f"{d}/remote.trace", 3); mir = load(f"{d}/mirror.trace", 6)
keys = sorted(set(rep) & set(mir))
st = {k: [] for k in ["bassd+local wake", "publish->serve stamp", "serve stamp->put", "put->mirror cb", "cb->replica done", "replica done->reader wake", "end to end"]}
rows = []
for k in keys:
    ff, mono, send, put, cb, done = mir[k]
    due = mono + chunk_ns
    w = rep[k][2]
    row = [send - due, put - send, cb - put, done - cb, w - done]
    rows.append((w - due, row, k))
    for n, v in zip(list(st)[1:6], row): st[n].append(v)
    st["end to end"].append(w - due)
    if k in loc: st["bassd+local wake"].append(loc[k][2] - due)
q = lambda v, p: sorted(v)[round((len(v) - 1) * p)] if v else float('nan')
print(f"chunks joined: {len(keys)} (local {len(loc)}, mirror {len(mir)}, replica {len(rep)})")
for n, v in st.items():
    print(f"{n:28s} p50 {q(v,.5)/1e3:8.0f}  p99 {q(v,.99)/1e3:8.0f}  p99.9 {q(v,.999)/1e3:8.0f}  max {max(v)/1e3 if v else 0:8.0f} us")
rows.sort(reverse=True)
worst = rows[:max(1, len(rows)//100)]
names = list(st)[1:6]
blame = [0]*5
for e, r, k in worst: blame[max(range(5), key=lambda i: r[i])] += 1
print("worst 1%: stage that is the largest part:", {names[i]: blame[i] for i in range(5)})
mean = [sum(r[1][i] for r in worst)/len(worst)/1e3 for i in range(5)]
print("worst 1%: mean per stage (us):", {names[i]: round(mean[i]) for i in range(5)})
