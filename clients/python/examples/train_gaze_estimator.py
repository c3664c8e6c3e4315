"""Trains a small gaze estimator for a few steps on samples streamed from
gazesplatd (RedirectedGazeDataset): random gaze targets in +-25 deg pitch,
+-35 deg yaw for each source face, new ones each epoch (set_epoch); L1 loss
on (pitch, yaw) in radians. Needs the package gazesplat with its extra
[torch] (pip install 'clients/python[torch]', or the Debian package with
python3-torch).

    python3 train_gaze_estimator.py --addr unix:/run/gazesplat/gazesplatd.sock \
        --steps 200 face0.png face1.png ...
"""
import argparse
import itertools
import os
import sys
import time

import torch

try:
    from gazesplat.dataset import RedirectedGazeDataset
except ImportError:  # run from the source tree: the compatibility modules find the build's package
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
    from gazesplat_dataset import RedirectedGazeDataset


class SmallGazeNet(torch.nn.Module):
    """Four strided convolutions, global pooling, a linear head -> (pitch, yaw)."""

    def __init__(self, width=16):
        super().__init__()
        layers, c = [], 3
        for k in range(4):
            layers += [torch.nn.Conv2d(c, width * 2 ** k, 3, stride=2, padding=1), torch.nn.ReLU()]
            c = width * 2 ** k
        self.features = torch.nn.Sequential(*layers)
        self.head = torch.nn.Linear(c, 2)

    def forward(self, x):
        return self.head(self.features(x).mean(dim=(2, 3)))


def epochs(ds, loader):
    """The loader's batches, epoch after epoch, each with its own targets."""
    for epoch in itertools.count():
        ds.set_epoch(epoch)
        yield from loader


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("images", nargs="+", help="normalized face images (PNG/JPEG)")
    ap.add_argument("--addr", default=None, help="gazesplatd address (default $GAZESPLAT_ADDR)")
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--fit-iters", type=int, default=0, help="subject fit iterations (0: server default)")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    torch.manual_seed(a.seed)

    def draw(rng):
        return (rng.uniform(-25, 25), rng.uniform(-35, 35))

    ds = RedirectedGazeDataset(a.images, gaze_targets=draw, targets_per_source=a.batch, addr=a.addr,
                               fit_iters=a.fit_iters, batch=a.batch, seed=a.seed)
    loader = torch.utils.data.DataLoader(ds, batch_size=a.batch)
    net = SmallGazeNet()
    opt = torch.optim.Adam(net.parameters(), lr=a.lr)
    t0, losses = time.time(), []
    for step, batch in enumerate(epochs(ds, loader)):
        if step >= a.steps:
            break
        pred = net(batch["image"])
        loss = torch.nn.functional.l1_loss(pred, batch["gaze"])
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
        print("step %d loss %.4f (%.1f s)" % (step, loss.item(), time.time() - t0), flush=True)
    if not losses:
        print("no samples", file=sys.stderr)
        return 1
    print("trained %d steps, first loss %.4f, last %.4f" % (len(losses), losses[0], losses[-1]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
