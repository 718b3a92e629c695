import json, numpy as np
for f in ["decl_thin","decl_ft","decl_26"]:
    rows=[json.loads(l) for l in open(f"/tmp/{f}.jsonl")]
    for alive in (True, False):
        r=[x for x in rows if x["alive"]==alive and x["own_off"] is not None]
        if not r: continue
        g=lambda k: np.array([x[k] for x in r])
        print(f, "FALSE" if alive else "TRUE", len(r), "own_off", np.percentile(g("own_off"),[10,25,50,75,90]).round(0), "j_off", np.percentile(g("j_off"),[10,50,90]).round(0),
              "true_d", np.percentile(g("true_d"),[10,50,90]).round(0), "pred d", np.percentile(g("d"),[10,50,90]).round(0))
        for thr in (60,100,150):
            print("    own_off >", thr, (g("own_off")>thr).sum())
print("\nnominal moving (> 1 m/s) at the newest missed instant, either end:")
for f in ["decl_thin","decl_ft","decl_26"]:
    rows=[json.loads(l) for l in open(f"/tmp/{f}.jsonl")]
    for alive in (True, False):
        r=[x for x in rows if x["alive"]==alive]
        if r: print(f, "FALSE" if alive else "TRUE", len(r), "moving share %.2f" % np.mean([(x["vj"]>1) or (x["va"]>1) for x in r]))
