import math
R0=9.0
modes=[(2,2.0,0.3),(3,1.5,1.1),(4,0.5,2.0),(6,0.15,0.5)]
def r(t): return R0+sum(a*math.cos(k*t+p) for k,a,p in modes)
def dr(t): return sum(-a*k*math.sin(k*t+p) for k,a,p in modes)
def ddr(t): return sum(-a*k*k*math.cos(k*t+p) for k,a,p in modes)
N=4000
minR=1e9; L=0; prev=None
for i in range(N):
    t=2*math.pi*i/N
    rr,d1,d2=r(t),dr(t),ddr(t)
    k=(rr*rr+2*d1*d1-rr*d2)/(rr*rr+d1*d1)**1.5
    if abs(k)>1e-9: minR=min(minR,abs(1/k))
    x,y=rr*math.cos(t),rr*math.sin(t)
    if prev: L+=math.hypot(x-prev[0],y-prev[1])
    prev=(x,y)
print("min radius",minR,"length",L)
# points every ~0.5 m of arc
n=int(L/0.5)
out=["# cabc's long track: a closed curve about %.0f m long whose width varies from 1.1 m to 1.8 m." % L,
     "# F1TENTH format (github.com/f1tenth/f1tenth_racetracks): one centre-line point a line, the widths to its",
     "# right and left of the driving direction. Made by this project (tracks/README.md says how).",
     "# x_m, y_m, w_tr_right_m, w_tr_left_m"]
# equal arc spacing via fine table
ts=[2*math.pi*i/N for i in range(N+1)]
pts=[(r(t)*math.cos(t),r(t)*math.sin(t)) for t in ts]
cum=[0]
for i in range(1,len(pts)): cum.append(cum[-1]+math.hypot(pts[i][0]-pts[i-1][0],pts[i][1]-pts[i-1][1]))
j=0
for i in range(n):
    s=L*i/n
    while cum[j+1]<s: j+=1
    f=(s-cum[j])/(cum[j+1]-cum[j])
    t=ts[j]+f*(ts[j+1]-ts[j])
    x,y=r(t)*math.cos(t),r(t)*math.sin(t)
    u=2*math.pi*s/L
    wr=0.55+0.35*(0.5+0.5*math.sin(2*u+0.4))
    wl=0.55+0.35*(0.5+0.5*math.sin(3*u+1.9))
    out.append("%.4f, %.4f, %.4f, %.4f"%(x,y,wr,wl))
open(__import__("os").path.join(__import__("os").path.dirname(__file__), "long.csv"), "w").write("\n".join(out)+"\n")
print(n,"points")
