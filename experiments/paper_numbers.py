"""The paper's reported numbers (FeelAnyForce, ICRA 2025; real hardware), for side-by-side tables.

Normalized L1 error in percent; the paper does not define its normalization (see ffjax.metrics).
"""

OBJECTS = ("banana", "brown_egg", "strawberry", "marker", "wooden_spatula", "ellipsoid_ycb", "nectarine",
           "green_apple", "wrench", "heart")
OBJECT_LABELS = ("Banana", "Brown egg", "Strawberry", "Marker", "Wooden spatula", "Ellipsoid", "Nectarine",
                 "Green apple", "Wrench", "Heart")

TABLE1 = {  # unseen objects, trained on sensor 1 gel 1
    "resnet_rd": (4.0, 5.4, 5.9, 5.2, 7.2, 5.0, 4.5, 4.7, 3.3, 7.8, 5.3),
    "dino_f_rd": (6.3, 6.9, 13.2, 11.3, 6.7, 6.8, 3.4, 5.8, 15.0, 9.2, 8.5),
    "dino_r": (4.9, 6.3, 5.1, 3.6, 5.4, 5.3, 5.2, 6.1, 2.3, 7.6, 5.2),
    "dino_rd": (3.5, 4.5, 3.0, 4.3, 4.9, 3.4, 4.3, 5.0, 3.1, 5.8, 4.2),
}

SENSORS = tuple(f"mini-{u}-gel{g}" for u in (1, 2, 3) for g in (1, 2, 3))
TABLE2 = {  # sensor 1..3 x gel 1..3, then the mean
    "resnet_rd": (3.9, 5.2, 6.4, 7.7, 5.6, 5.1, 7.2, 5.8, 7.3, 6.0),
    "dino_f_r": (7.4, 10.5, 7.4, 11.8, 8.3, 8.5, 7.8, 9.8, 8.0, 8.8),
    "dino_r": (4.9, 4.3, 4.5, 8.0, 5.8, 5.5, 6.6, 6.3, 6.4, 5.8),
    "dino_rd": (4.2, 4.8, 5.2, 6.3, 4.8, 5.1, 6.1, 6.3, 6.2, 5.4),
}

CALIB_TARGETS = ("mini-2-gel1", "mini-3-gel2", "digit")
TABLE3 = {  # after calibration with 100 Big Sphere images
    "resnet_rd": (4.7, 4.9, 53.4),
    "dino_f_r": (7.2, 7.9, 16.0),
    "dino_r": (5.4, 6.0, 29.6),
    "dino_rd": (4.2, 4.3, 9.2),
}
# Relative degradation of the other (uncalibrated) sensors after calibrating, as the paper reports it:
# 4% for DINO RD against 25% / 14% / 12% for the others (the paper does not say which is which).
DEGRADATION_DINO_RD = 4.0


def sensor_label(key: str) -> str:
    """'mini-2-gel3' -> 'mini-2/gel-3' (results.json's key style); 'digit' stays."""
    if key.startswith("mini-"):
        unit, gel = key[len("mini-"):].split("-gel")
        return f"mini-{unit}/gel-{gel}"
    return key
