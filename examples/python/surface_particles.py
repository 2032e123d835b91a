#!/usr/bin/env python3
"""Surfaces a numpy particle set with Surfacer and writes the mesh as PLY.

    PYTHONPATH=build/python /usr/bin/python3 examples/python/surface_particles.py out.ply [--server HOST:PORT]

The particles are a jittered lattice filling two overlapping balls (a splash-like blob); without --server the mesh is
made by an in-process server.
"""

import argparse

import numpy as np

import surfacer


def two_balls(spacing=0.02, seed=1):
    axis = np.arange(-0.5, 0.5 + 1e-9, spacing)
    points = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
    inside = (np.linalg.norm(points - [-0.12, 0, 0], axis=1) < 0.25) | (np.linalg.norm(points - [0.15, 0, 0.05], axis=1) < 0.2)
    points = points[inside]
    return points + np.random.default_rng(seed).uniform(-0.2, 0.2, points.shape) * spacing


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("output", help="the PLY file to write")
    parser.add_argument("--server", help="HOST:PORT of a surfacer-server (default: an in-process server)")
    args = parser.parse_args()

    particles = two_balls()
    with surfacer.Client(args.server) as client:
        for frame in client.particles([particles], r_inner=0.02):
            frame.write(args.output)
            check = frame.stats["check"]
            print("%d particles -> %d vertices, %d triangles (closed: %s) -> %s"
                  % (len(particles), len(frame.vertices), len(frame.triangles), check["closed"], args.output))


if __name__ == "__main__":
    main()
