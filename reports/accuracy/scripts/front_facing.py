"""Front-facing triangles of each method's budget cut in the sweep's relit cells (no judge): where plod's triangles go.
    .venv/bin/python reports/accuracy/scripts/front_facing.py horse,armadillo-70k,dragon-100k,lucy-100k,torus-240-120-5"""
import sys; sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[3]))
import json, sys, numpy as np, optim
from experiments.accuracy import _Mesh, _view, DEFAULTS, load_meshes
rows=[json.loads(l) for l in open('reports/accuracy/results.jsonl')]
cfg=dict(DEFAULTS)
def front(vv, ff, eye):
    vv=np.asarray(vv,float); ff=np.asarray(ff)
    n=np.cross(vv[ff[:,1]]-vv[ff[:,0]], vv[ff[:,2]]-vv[ff[:,0]])
    return int(((n*(eye-vv[ff].mean(1))).sum(1)>0).sum())
for name, v, f, c in load_meshes(cfg):
    if name not in sys.argv[1].split(','): continue
    m=_Mesh(name,v,f,c); tree=m.tree['relit']; T=tree.n_triangles
    for g in (0.0, 16.0):
        cid=f"{name}/v0/g{g:g}/relit"; r=[x for x in rows if x['cell']==cid][0]
        view=_view(m, r['direction'], g, 'relit', cfg, True); eye=np.asarray(view.eye,float)
        keys=optim.score(tree, view)
        for b in (0.03,0.08):
            res=optim.extract(tree, optim.budget_cut(tree, keys, int(b*T), monotone='trust')); tgt=len(res[1])
            out=[f"{cid} {b}: {tgt} tris; front: perc {front(res[0],res[1],eye)}"]
            for meth in ('size','geometric'):
                k=optim.score(tree, view, None, meth); rr=optim.extract(tree, optim.budget_cut(tree,k,tgt,monotone='trust'))
                out.append(f"{meth} {front(rr[0],rr[1],eye)}")
            for p in ('meshoptimizer','fast_simplification'):
                rr=m.peer(p,'relit',tgt); out.append(f"{p} {front(rr[0],rr[1],eye)}")
            jod={x['method']:x['jod'] for x in rows if x['cell']==cid and x['budget']==b}
            out.append("JOD "+" ".join(f"{k[:4]}={v:.3f}" for k,v in jod.items() if not k.startswith('model')))
            print(" | ".join(out), flush=True)
