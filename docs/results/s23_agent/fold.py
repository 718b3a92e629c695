"""Inclusive and self shares of the folded stacks in DIR/*.txt (cpu_sampler_sitecustomize.py): fold.py DIR [N]."""
import sys, collections, re, glob
d=sys.argv[1]; N=int(sys.argv[2]) if len(sys.argv)>2 else 80
incl=collections.Counter(); selfc=collections.Counter(); tot=0
for fn in glob.glob(d+'/*.txt'):
    for line in open(fn):
        stack, n = line.rstrip('\n').rsplit(' ',1); n=int(n)
        frames=stack.split(';'); tot+=n
        seen=set()
        for f in frames:
            k=re.sub(r':\d+\)$',')',f)
            if k in seen: continue
            seen.add(k); incl[k]+=n
        selfc[frames[-1]]+=n
print('samples', tot, '~cpu_s', tot*0.004)
for k,v in incl.most_common(N): print(f'{100*v/tot:5.1f} {k}')
print('---self')
for k,v in selfc.most_common(40): print(f'{100*v/tot:5.1f} {k}')
