"""Drive a run's full-state policy from the fixed spawn and print, step by step, its action beside the MPCC expert's.

    python python/examples/drive_policy.py runs/<run>/best-policy.safetensors [--steps 300] [--every 1]

The published policy (`best-policy.safetensors`, `final-policy.safetensors`) takes raw states: any standardisation
is folded into its first layer. It is the 6 -> 3 x 128 -> 2 ReLU MLP of the full-state presets, read here with numpy
alone (a safetensors file is an 8-byte header length, a JSON header and the raw tensors). Where the two actions part
is where the policy has not learnt the expert: docs/REPRODUCTION.md, "The V-B recipe", shows what it found.
"""

import argparse
import json
import struct

import numpy as np

import cabc


def load_safetensors(path):
    raw = open(path, "rb").read()
    (n,) = struct.unpack("<Q", raw[:8])
    header = json.loads(raw[8 : 8 + n])
    data = raw[8 + n :]
    dtypes = {"F32": np.float32, "F64": np.float64}
    tensors = {}
    for name, meta in header.items():
        if name == "__metadata__":
            continue
        start, end = meta["data_offsets"]
        tensors[name] = np.frombuffer(data[start:end], dtype=dtypes[meta["dtype"]]).reshape(meta["shape"])
    return tensors


def mlp_policy(weights):
    layers = sorted({int(k.split(".")[1]) for k in weights if k.startswith("mlp.")})
    if not layers:
        raise SystemExit("not a full-state policy: no mlp.* tensors (a camera policy has a trunk)")

    def act(state):
        h = np.asarray(state, dtype=np.float32)
        for i in layers[:-1]:
            h = np.maximum(0.0, weights[f"mlp.{i}.weight"] @ h + weights[f"mlp.{i}.bias"])
        last = layers[-1]
        return weights[f"mlp.{last}.weight"] @ h + weights[f"mlp.{last}.bias"]

    return act


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("policy", help="a policy's safetensors file")
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--every", type=int, default=1, help="print every this many steps")
    args = parser.parse_args()
    policy = mlp_policy(load_safetensors(args.policy))
    expert = cabc.expert("mpcc")
    env = cabc.make("BarcTrack-v0")
    obs, info = env.reset(options={"spawn": "fixed"})
    print("step  v_long v_tran omega      s x_tran  e_psi |  policy (a, steer) | expert (a, steer)")
    for t in range(args.steps):
        u = policy(obs)
        e = expert(obs)
        if t % args.every == 0:
            print(
                f"{t:4d} {obs[0]:7.2f} {obs[1]:+6.2f} {obs[2]:+5.2f} {obs[3]:6.2f} {obs[4]:+6.2f} {obs[5]:+6.2f} |"
                f" ({u[0]:+5.2f}, {u[1]:+6.3f}) | ({e[0]:+5.2f}, {e[1]:+6.3f})"
            )
        obs, _, terminated, truncated, info = env.step(u)
        if terminated or truncated:
            print(f"ended at step {t + 1}: {info['end_reason']}, {info['laps']} laps")
            return
    print(f"still driving after {args.steps} steps, {info['laps']} laps")


if __name__ == "__main__":
    main()
