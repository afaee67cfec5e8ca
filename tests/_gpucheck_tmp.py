import time, torch, numpy as np
from vid2haircut.head import get_head
h = get_head("proxy-v1")
p = (torch.randn(200000, 3, dtype=torch.float64) * 0.12)
ref = h.sdf(p)
for dt in (torch.float32, torch.float64):
    q = p.to("cuda", dt).requires_grad_(True)
    d = h.sdf(q); d.sum().backward()
    assert d.device.type == "cuda" and d.dtype == dt and q.grad.device.type == "cuda"
    print(dt, "max |cuda-cpu|", (d.detach().cpu().double() - ref).abs().max().item(),
          "grad finite", bool(torch.isfinite(q.grad).all()))
torch.cuda.synchronize(); t = time.time()
x = torch.randn(4_000_000, 3, device="cuda") * 0.12
for _ in range(10): h.sdf(x)
torch.cuda.synchronize(); print("4M lookups x10", time.time() - t, torch.cuda.get_device_name())
