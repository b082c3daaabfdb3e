#!/usr/bin/env python3
"""Mean per-channel difference of two 8-bit RGB(A) PNGs, in levels, and the share of pixels off by
more than 24 (the golden-image measure of tests/common/mod.rs). Standard library only.
usage: png_diff.py A.png B.png"""
import zlib, struct, sys
def load(p):
    b=open(p,'rb').read(); assert b[:8]==b'\x89PNG\r\n\x1a\n'
    i=8; idat=b''; w=h=0
    while i<len(b):
        n,=struct.unpack('>I',b[i:i+4]); t=b[i+4:i+8]; d=b[i+8:i+8+n]; i+=12+n
        if t==b'IHDR': w,h,bd,ct=struct.unpack('>IIBB',d[:10]); assert bd==8; ch={2:3,6:4}[ct]
        elif t==b'IDAT': idat+=d
    raw=zlib.decompress(idat); st=w*ch; out=bytearray(); prev=bytearray(st); k=0
    for y in range(h):
        f=raw[k]; line=bytearray(raw[k+1:k+1+st]); k+=1+st
        for x in range(st):
            a=line[x-ch] if x>=ch else 0; c=prev[x-ch] if x>=ch else 0; up=prev[x]
            if f==1: line[x]=(line[x]+a)&255
            elif f==2: line[x]=(line[x]+up)&255
            elif f==3: line[x]=(line[x]+(a+up)//2)&255
            elif f==4:
                p=a+up-c; pa,pb,pc=abs(p-a),abs(p-up),abs(p-c)
                line[x]=(line[x]+(a if pa<=pb and pa<=pc else up if pb<=pc else c))&255
        out+=line; prev=line
    return w,h,ch,out
w,h,ch,a=load(sys.argv[1]); _,_,ch2,b=load(sys.argv[2])
tot=0; big=0
for i in range(w*h):
    d=[abs(a[i*ch+c]-b[i*ch2+c]) for c in range(3)]; tot+=sum(d); big+= max(d)>24
print(f"mean {tot/(3*w*h):.3f} levels, {100*big/(w*h):.3f}% pixels off by > 24")
