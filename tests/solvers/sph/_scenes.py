"""Small scenes shared by the SPH tests (the seed's examples at test resolutions)."""

SEED_EXAMPLE1 = dict(matrix=dict(E=900.0, nu=0.33), inclusion=dict(E=1000.0, nu=0.28),
                     loading="eigenstrain", eigenstrain=0.01,
                     inclusions=[dict(centre=[0.0, 0.0], semi_axes=[20.0, 20.0])])


def example1(layout="polar", spacing=2.0, **extra):
    scene = dict(SEED_EXAMPLE1, layout=layout, spacing=spacing)
    if layout == "polar":
        scene["outer_radius"] = 60.0
    else:
        scene["width"] = scene["height"] = 120.0
    scene.update(extra)
    return scene


def example3(**extra):
    """The seed's Example 2/3 plate (100 µm, 9 random ellipses, 0.05 µm steps), coarse."""
    scene = dict(layout="random", width=100e-6, height=100e-6, spacing=2.5e-6,
                 random=dict(count=9, semi_axes_min=[6e-6, 3e-6], semi_axes_max=[10e-6, 6e-6],
                             layout_seed=3),
                 matrix=dict(E=1e6, nu=0.4), inclusion=dict(E=150e6, nu=0.3),
                 interface_strength=0.04e6, loading="tension", step=0.05e-6, steps=40)
    scene.update(extra)
    return scene
