"""Inclusive shares of what runs under function ROOT (a qualified name) in DIR/*.txt: sub.py DIR ROOT [N]."""
import sys, collections, re, glob
d=sys.argv[1]; root=sys.argv[2]; N=int(sys.argv[3]) if len(sys.argv)>3 else 40
child=collections.Counter(); tot=0; rt=0
for fn in glob.glob(d+'/*.txt'):
    for line in open(fn):
        stack, n = line.rstrip('\n').rsplit(' ',1); n=int(n)
        frames=[re.sub(r':\d+\)$',')',f) for f in stack.split(';')]
        tot+=n
        if root in [f.split(' (')[0] for f in frames]:
            i=max(i for i,f in enumerate(frames) if f.split(' (')[0]==root)
            rt+=n
            seen=set()
            for f in frames[i+1:]:
                if f in seen: continue
                seen.add(f); child[f]+=n
            if i==len(frames)-1: child['<self>']+=n
print(root, f'{100*rt/tot:.1f}% of', tot)
for k,v in child.most_common(N): print(f'{100*v/tot:5.2f} {k}')
