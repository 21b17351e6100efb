"""A compact PyTorch CREStereo written for the side-by-side bench of `crestereo bench`.

Written from the architecture facts in shared/reference/crestereo/README.md (same state-dict
names as the reference, so weights_seed0.pt loads). Checked against the fixtures:
`python torch_reference.py check FIXTURES_DIR`; timed with `python torch_reference.py bench`.
"""
import math
import os
import resource
import statistics
import sys
import time

import torch
import torch.nn as nn
import torch.nn.functional as F


class ResBlock(nn.Module):
    def __init__(self, cin, cout, stride):
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1)
        self.downsample = nn.Sequential(nn.Conv2d(cin, cout, 1, stride))

    def forward(self, x):
        y = F.relu(F.instance_norm(self.conv1(x)))
        y = F.relu(F.instance_norm(self.conv2(y)))
        return F.relu(F.instance_norm(self.downsample(x)) + y)


class Encoder(nn.Module):
    def __init__(self):
        super().__init__()
        self.conv1 = nn.Conv2d(3, 64, 7, 2, 3)
        self.layer1 = nn.Sequential(ResBlock(64, 64, 1), ResBlock(64, 64, 1))
        self.layer2 = nn.Sequential(ResBlock(64, 96, 2), ResBlock(96, 96, 1))
        self.layer3 = nn.Sequential(ResBlock(96, 128, 1), ResBlock(128, 128, 1))
        self.conv2 = nn.Conv2d(128, 256, 1)

    def forward(self, x):
        x = F.relu(F.instance_norm(self.conv1(x)))
        return self.conv2(self.layer3(self.layer2(self.layer1(x))))


class LoFTRLayer(nn.Module):
    def __init__(self, d=256, nhead=8):
        super().__init__()
        self.nhead = nhead
        self.q_proj = nn.Linear(d, d, bias=False)
        self.k_proj = nn.Linear(d, d, bias=False)
        self.v_proj = nn.Linear(d, d, bias=False)
        self.merge = nn.Linear(d, d, bias=False)
        self.mlp = nn.Sequential(nn.Linear(2 * d, 2 * d, bias=False), nn.ReLU(), nn.Linear(2 * d, d, bias=False))
        self.norm1 = nn.LayerNorm(d)
        self.norm2 = nn.LayerNorm(d)

    def forward(self, x, src):
        n, l, c = x.shape
        h = self.nhead
        q = F.elu(self.q_proj(x).view(n, l, h, -1)) + 1
        k = F.elu(self.k_proj(src).view(n, src.shape[1], h, -1)) + 1
        v = self.v_proj(src).view(n, src.shape[1], h, -1) / src.shape[1]
        kv = torch.einsum("nshd,nshv->nhdv", k, v)
        z = 1 / (torch.einsum("nlhd,nhd->nlh", q, k.sum(1)) + 1e-6)
        msg = torch.einsum("nlhd,nhdv,nlh->nlhv", q, kv, z) * src.shape[1]
        msg = self.norm1(self.merge(msg.reshape(n, l, c)))
        return x + self.norm2(self.mlp(torch.cat([x, msg], 2)))


class Wrap(nn.Module):
    def __init__(self):
        super().__init__()
        self.layers = nn.ModuleList([LoFTRLayer()])


class Update(nn.Module):
    def __init__(self):
        super().__init__()
        enc = nn.Module()
        enc.convc1 = nn.Conv2d(36, 256, 1)
        enc.convc2 = nn.Conv2d(256, 192, 3, 1, 1)
        enc.convf1 = nn.Conv2d(2, 128, 7, 1, 3)
        enc.convf2 = nn.Conv2d(128, 64, 3, 1, 1)
        enc.conv = nn.Conv2d(256, 126, 3, 1, 1)
        self.encoder = enc
        gru = nn.Module()
        for a in "zrq":
            setattr(gru, f"conv{a}1", nn.Conv2d(384, 128, (1, 5), 1, (0, 2)))
            setattr(gru, f"conv{a}2", nn.Conv2d(384, 128, (5, 1), 1, (2, 0)))
        self.gru = gru
        fh = nn.Module()
        fh.conv1 = nn.Conv2d(128, 256, 3, 1, 1)
        fh.conv2 = nn.Conv2d(256, 2, 3, 1, 1)
        self.flow_head = fh
        self.mask = nn.Sequential(nn.Conv2d(128, 256, 3, 1, 1), nn.ReLU(), nn.Conv2d(256, 144, 1))

    def forward(self, net, inp, corr, flow):
        e = self.encoder
        c = F.relu(e.convc2(F.relu(e.convc1(corr))))
        f = F.relu(e.convf2(F.relu(e.convf1(flow))))
        motion = torch.cat([F.relu(e.conv(torch.cat([c, f], 1))), flow], 1)
        x = torch.cat([inp, motion], 1)
        g = self.gru
        for i in "12":
            hx = torch.cat([net, x], 1)
            z = torch.sigmoid(getattr(g, "convz" + i)(hx))
            r = torch.sigmoid(getattr(g, "convr" + i)(hx))
            q = torch.tanh(getattr(g, "convq" + i)(torch.cat([r * net, x], 1)))
            net = (1 - z) * net + z * q
        fh = self.flow_head
        return net, 0.25 * self.mask(net), fh.conv2(F.relu(fh.conv1(net)))


def grid(n, h, w, dev):
    ys, xs = torch.meshgrid(torch.arange(h, device=dev), torch.arange(w, device=dev), indexing="ij")
    return torch.stack([xs, ys]).float()[None].expand(n, -1, -1, -1)


def sample(img, x, y):
    h, w = img.shape[-2:]
    g = torch.stack([2 * x / (w - 1) - 1, 2 * y / (h - 1) - 1], -1)
    return F.grid_sample(img, g, align_corners=True)


def windows(square):
    return [(dx, dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1)] if square else [(dx, 0) for dx in range(-4, 5)]


def corr_offset(l, r, flow, off, square):
    n, c, h, w = l.shape
    off = off.view(n, 9, 2, h, w)
    g = grid(n, h, w, l.device)
    x = torch.stack([g[:, 0] + flow[:, 0] + dx + off[:, k, 0] for k, (dx, dy) in enumerate(windows(square))], 1)
    y = torch.stack([g[:, 1] + flow[:, 1] + dy + off[:, k, 1] for k, (dx, dy) in enumerate(windows(square))], 1)
    s = sample(r, x.view(n, 9 * h, w), y.view(n, 9 * h, w)).view(n, 4, c // 4, 9, h, w)
    return (l.view(n, 4, c // 4, 1, h, w) * s).mean(2).reshape(n, 36, h, w)


def corr_warp(l, r, flow, square):
    n, c, h, w = l.shape
    g = grid(n, h, w, l.device)
    rw = sample(r, g[:, 0] + flow[:, 0], g[:, 1] + flow[:, 1])
    py, px = (1, 1) if square else (0, 4)
    rp = F.pad(rw, (px, px, py, py), mode="replicate")
    out = [(l * rp[:, :, dy + py:dy + py + h, dx + px:dx + px + w]).view(n, 4, c // 4, h, w).mean(2)
           for dx, dy in windows(square)]
    return torch.stack(out, 2).reshape(n, 36, h, w)


def convex_up(flow, mask):
    n, _, h, w = flow.shape
    m = torch.softmax(mask.view(n, 1, 9, 4, 4, h, w), 2)
    u = F.unfold(4 * flow, 3, padding=1).view(n, 2, 9, 1, 1, h, w)
    return (m * u).sum(2).permute(0, 1, 4, 2, 5, 3).reshape(n, 2, 4 * h, 4 * w)


def resize(x, size):
    return F.interpolate(x, size=size, mode="bilinear", align_corners=True)


def pos_enc(c, h, w, dev):
    div = torch.exp(torch.arange(0, c // 2, 2).float() * -1.0)[:, None, None]
    ypos = torch.ones(h, w).cumsum(0)[None]
    xpos = torch.ones(h, w).cumsum(1)[None]
    pe = torch.zeros(c, h, w)
    pe[0::4], pe[1::4] = torch.sin(xpos * div), torch.cos(xpos * div)
    pe[2::4], pe[3::4] = torch.sin(ypos * div), torch.cos(ypos * div)
    return pe.to(dev)


class CREStereo(nn.Module):
    def __init__(self):
        super().__init__()
        self.fnet = Encoder()
        self.update_block = Update()
        self.self_att_fn = Wrap()
        self.cross_att_fn = Wrap()
        self.conv_offset_16 = nn.Conv2d(256, 18, 3, 1, 1)
        self.conv_offset_8 = nn.Conv2d(256, 18, 3, 1, 1)

    def forward(self, left, right, iters=10, flow_init=None):
        n = left.shape[0]
        f1, f2 = self.fnet(torch.cat([2 * (left / 255) - 1, 2 * (right / 255) - 1])).split(n)
        h4, w4 = f1.shape[-2:]
        f1_8, f2_8 = F.avg_pool2d(f1, 2), F.avg_pool2d(f2, 2)
        off8 = (torch.sigmoid(self.conv_offset_8(f1_8)) - 0.5) * 2
        net, inp = torch.tanh(f1[:, :128]), F.relu(f1[:, 128:])
        net8, inp8 = F.avg_pool2d(net, 2), F.avg_pool2d(inp, 2)
        f1_16, f2_16 = F.avg_pool2d(f1, 4), F.avg_pool2d(f2, 4)
        off16 = (torch.sigmoid(self.conv_offset_16(f1_16)) - 0.5) * 2
        net16, inp16 = F.avg_pool2d(net, 4), F.avg_pool2d(inp, 4)
        h16, w16 = f1_16.shape[-2:]
        pe = pos_enc(256, h16, w16, left.device)
        tok = lambda t: t.flatten(2).transpose(1, 2)
        untok = lambda t: t.transpose(1, 2).reshape(n, 256, h16, w16)
        sa = self.self_att_fn.layers[0]
        t1, t2 = tok(f1_16 + pe), tok(f2_16 + pe)
        t1, t2 = sa(t1, t1), sa(t2, t2)
        ca = self.cross_att_fn.layers[0]
        preds = []
        if flow_init is not None:
            flow = -(h4 / flow_init.shape[2]) * resize(flow_init, (h4, w4))
        else:
            flow16 = torch.zeros(n, 2, h16, w16, device=left.device)
            for i in range(iters // 2):
                flow16 = flow16.detach()
                a = ca(t1, t2)
                b = ca(t2, a)
                corr = corr_offset(untok(a), untok(b), flow16, off16, i % 2 == 1)
                net16, mask, d = self.update_block(net16, inp16, corr, flow16)
                flow16 = flow16 + d
                flow = convex_up(flow16, mask)
                preds.append(-4 * resize(flow, (4 * flow.shape[2], 4 * flow.shape[3])))
            flow8 = -(f1_8.shape[2] / flow.shape[2]) * resize(flow, f1_8.shape[-2:])
            for i in range(iters // 2):
                flow8 = flow8.detach()
                corr = corr_offset(f1_8, f2_8, flow8, off8, i % 2 == 1)
                net8, mask, d = self.update_block(net8, inp8, corr, flow8)
                flow8 = flow8 + d
                flow = convex_up(flow8, mask)
                preds.append(-2 * resize(flow, (2 * flow.shape[2], 2 * flow.shape[3])))
            flow = -(h4 / flow.shape[2]) * resize(flow, (h4, w4))
        for i in range(iters):
            flow = flow.detach()
            corr = corr_warp(f1, f2, flow, i % 2 == 1)
            net, mask, d = self.update_block(net, inp, corr, flow)
            flow = flow + d
            preds.append(-convex_up(flow, mask))
        return preds


def seq_loss(preds, disp, valid, gamma):
    gt = torch.stack([disp, torch.zeros_like(disp)], 1)
    n = len(preds)
    return sum(gamma ** (n - i - 1) * (valid[:, None] * (p - gt).abs()).mean() for i, p in enumerate(preds))


def check(fixtures):
    import numpy as np
    m = CREStereo()
    m.load_state_dict(torch.load(f"{fixtures}/weights_seed0.pt"))
    t = f"{fixtures}/train_b2_64x128"
    ld = lambda p: torch.from_numpy(np.load(p)).float()
    preds = m(ld(f"{t}/left.npy"), ld(f"{t}/right.npy"), 10)
    ref = ld(f"{t}/preds.npy")
    print("max|pred - fixture|", max((p - r).abs().max().item() for p, r in zip(preds, ref)))
    print("loss", seq_loss(preds, ld(f"{t}/gt_disp.npy"), ld(f"{t}/valid.npy"), 0.8).item())


DEVICE = os.environ.get("CRESTEREO_TORCH_DEVICE", "cpu")
# A checkout of the public PyTorch port (github.com/ibaiGorordo/CREStereo-Pytorch, not committed
# here): when set, `bench` times that port's network instead of the one in this file.
PORT = os.environ.get("CRESTEREO_TORCH_PORT")


class PortAdapter(nn.Module):
    """The port's `CREStereo` behind this file's call signature `(left, right, iters, flow_init)`."""

    def __init__(self, port_dir):
        super().__init__()
        sys.path.insert(0, port_dir)
        from nets.crestereo import CREStereo as Port  # the port's own package

        self.net = Port(max_disp=256, mixed_precision=False, test_mode=False)

    def forward(self, left, right, iters, flow_init=None):
        return self.net(left, right, flow_init=flow_init, iters=iters)


def make_model():
    return (PortAdapter(PORT) if PORT else CREStereo()).to(DEVICE)


def capability():
    """The instruction set PyTorch's own kernels dispatch to, and the CPU's model name."""
    cap = torch.backends.cpu.get_cpu_capability()
    model = "unknown CPU"
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"torch {torch.__version__}, kernels {cap}, {model}"
# on CUDA: one warm-up run, then the median of this many (CPU: one run, like `crestereo bench`)
REPEATS = int(os.environ.get("CRESTEREO_TORCH_REPEATS", "3")) if DEVICE != "cpu" else 1


def peak_rss_mib():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def sync():
    if DEVICE != "cpu":
        torch.cuda.synchronize()


def memory_note():
    if DEVICE == "cpu":
        return f"peak RSS {peak_rss_mib():.0f} MiB"
    return (f"peak RSS {peak_rss_mib():.0f} MiB, device {torch.cuda.get_device_name()}, "
            f"max_memory_allocated {torch.cuda.max_memory_allocated() / 2**20:.0f} MiB")


def bench_train(threads, n, h, w, iters):
    m = make_model()
    opt = torch.optim.Adam(m.parameters(), lr=4e-4, betas=(0.9, 0.999), eps=1e-8)
    l, r = torch.rand(n, 3, h, w, device=DEVICE) * 255, torch.rand(n, 3, h, w, device=DEVICE) * 255
    disp, valid = torch.rand(n, h, w, device=DEVICE) * 64, torch.ones(n, h, w, device=DEVICE)
    runs = []
    for rep in range(REPEATS + (DEVICE != "cpu")):
        opt.zero_grad(set_to_none=True)
        sync()
        s = time.time()
        loss = seq_loss(m(l, r, iters), disp, valid, 0.9)
        sync()
        fwd = time.time() - s
        loss.backward()
        sync()
        bwd = time.time() - s - fwd
        opt.step()
        sync()
        runs.append((fwd, bwd, time.time() - s))
    fwd, bwd, total = (statistics.median(v) for v in zip(*runs[-REPEATS:]))
    print(f"torch train step (batch {n}, {h}x{w}, iters {iters}, threads {threads}): forward {fwd:.3f}s, "
          f"backward {bwd:.3f}s, total incl. Adam {total:.3f}s, {memory_note()}")


def bench_infer(threads, h, w, iters=20):
    """The reference two-pass procedure; pads (replicate, bottom/right) to a multiple of 32 like
    `crestereo infer`."""
    m = make_model()
    l0, r0 = torch.rand(1, 3, h, w, device=DEVICE) * 255, torch.rand(1, 3, h, w, device=DEVICE) * 255
    ph, pw = -(-h // 32) * 32, -(-w // 32) * 32
    runs = []
    with torch.inference_mode():
        for rep in range(REPEATS + (DEVICE != "cpu")):
            sync()
            s = time.time()
            l, r = l0, r0
            if (ph, pw) != (h, w):
                l = F.pad(l, (0, pw - w, 0, ph - h), mode="replicate")
                r = F.pad(r, (0, pw - w, 0, ph - h), mode="replicate")
            p = m(resize(l, (ph // 2, pw // 2)), resize(r, (ph // 2, pw // 2)), iters)[-1]
            out = m(l, r, iters, flow_init=p)[-1][:, :, :h, :w].cpu()
            assert out.shape[-2:] == (h, w)
            runs.append(time.time() - s)
    print(f"torch inference (1x{h}x{w}, two-pass, {iters} iters, threads {threads}): "
          f"{statistics.median(runs[-REPEATS:]):.3f}s, {memory_note()}")


def bench(argv):
    """`bench THREADS train [N H W ITERS]` or `bench THREADS infer [H W]` (defaults: the paper's
    training crop 2x384x512 with 10 iterations; inference 480x640)."""
    threads = int(argv[0]) if argv else 2
    what = argv[1] if len(argv) > 1 else "train"
    sizes = [int(v) for v in argv[2:]]
    torch.set_num_threads(threads)
    torch.manual_seed(0)
    # CRESTEREO_TORCH_TF32=off: no TensorFloat-32 anywhere (the float32 that `crestereo
    # --precision f32` computes in); unset or `default`: PyTorch's defaults (TF32 in cuDNN
    # convolutions, none in matrix products).
    if os.environ.get("CRESTEREO_TORCH_TF32", "default") == "off":
        torch.backends.cudnn.allow_tf32 = False
        torch.backends.cuda.matmul.allow_tf32 = False
    b = torch.backends
    tf32 = f"cudnn.allow_tf32 {b.cudnn.allow_tf32}, matmul.allow_tf32 {b.cuda.matmul.allow_tf32}"
    print(f"{'port ' + PORT if PORT else 'reference'}: {capability()}; {tf32}", flush=True)
    if what == "train":
        bench_train(threads, *(sizes or [2, 384, 512, 10]))
    else:
        bench_infer(threads, *(sizes or [480, 640]))


def parity(case_dir, weights):
    """`parity CASE_DIR WEIGHTS`: the two-pass prediction of eval_cascade_1x128x192 on DEVICE with
    TensorFloat-32 off, as PyTorch sets it (cuDNN on, matrix products off) and all on, each against
    pred_full.npy (float32 on a CPU): the size of the error reduced-precision matrix units give
    this network on this input, to set a backend's CUDA parity figure against."""
    import numpy as np
    ref = np.load(f"{case_dir}/pred_full.npy")[0, 0]
    ld = lambda name: torch.from_numpy(np.load(f"{case_dir}/{name}")).float().to(DEVICE)
    m = CREStereo().to(DEVICE)
    m.load_state_dict(torch.load(weights, map_location=DEVICE))
    b = torch.backends
    defaults = (b.cudnn.allow_tf32, b.cuda.matmul.allow_tf32)
    for name, (conv, mm) in (("tf32 off", (False, False)), ("torch default", defaults),
                             ("tf32 on", (True, True))):
        b.cudnn.allow_tf32, b.cuda.matmul.allow_tf32 = conv, mm
        with torch.inference_mode():
            p = m(ld("left_dw2.npy"), ld("right_dw2.npy"), 20)[-1]
            out = m(ld("left.npy"), ld("right.npy"), 20, flow_init=p)[-1][0, 0].cpu().numpy()
        err = np.abs(out - ref)
        print(f"torch {DEVICE} {name} (cudnn.allow_tf32 {conv}, matmul.allow_tf32 {mm}): "
              f"max |pred - pred_full| = {err.max():.3e}, mean {err.mean():.3e}")
    b.cudnn.allow_tf32, b.cuda.matmul.allow_tf32 = defaults


if __name__ == "__main__":
    if sys.argv[1] == "check":
        check(sys.argv[2])
    elif sys.argv[1] == "parity":
        parity(sys.argv[2], sys.argv[3])
    else:
        bench(sys.argv[2:])
