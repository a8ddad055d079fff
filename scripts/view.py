"""Static view of a preset's mechanism (the reports' task 3): no stepping.

python scripts/view.py --preset default                 # MuJoCo's passive viewer
MUJOCO_GL=egl python scripts/view.py --save out.png     # headless PNG from the side camera
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--preset", default="default")
    p.add_argument("--save", default=None, help="write a PNG instead of opening the viewer")
    p.add_argument("--q-deg", type=float, nargs=2, default=(20.0, -35.0), help="pose (deg)")
    p.add_argument("--width", type=int, default=800)
    p.add_argument("--height", type=int, default=600)
    args = p.parse_args(argv)
    if args.save:
        os.environ.setdefault("MUJOCO_GL", "egl")
    import mujoco

    from tendon2r_gym.config import load_preset
    from tendon2r_gym.mechanism import Mechanism
    from tendon2r_gym.model import CAMERA, build_model

    model = build_model(Mechanism.from_dict(load_preset(args.preset)["mechanism"]))
    model.vis.global_.offwidth, model.vis.global_.offheight = args.width, args.height
    data = mujoco.MjData(model)
    data.qpos[:] = np.radians(args.q_deg)
    mujoco.mj_forward(model, data)  # positions only: the mechanism is shown, not simulated
    if args.save:
        import imageio.v2 as imageio

        with mujoco.Renderer(model, args.height, args.width) as renderer:
            renderer.update_scene(data, camera=CAMERA)
            image = renderer.render()
        Path(args.save).parent.mkdir(parents=True, exist_ok=True)
        imageio.imwrite(args.save, image)
        print("wrote", args.save)
        return
    import mujoco.viewer

    with mujoco.viewer.launch_passive(model, data) as viewer:
        while viewer.is_running():
            viewer.sync()


if __name__ == "__main__":
    main()
