"""Downstream tasks: weighing by pushing (Table IV) and grasping to a target force.

    from ffjax.tasks import pushing, grasping
    push = pushing.simulate_push(pushing.OBJECTS[0], pushing.PushConfig(), seed=0)
    frames, bg = pushing.render_push(push, "mini-1", (48, 64))
    row = pushing.weigh([push], [estimate(frames, bg)[:, 2]])      # Table IV numbers for the object
    trial = grasping.GraspTrial(grasping.CUP, grasping.GripperConfig(), seed=0, size=(48, 64))
    out = grasping.run_grasp(trial, 1.74, "reach", grasping.model_reader(trial, estimate))

`estimate` is any callable (frames, background) -> (N, 3) forces, e.g. sensing.ModelSensor(run_dir).
`python -m experiments.downstream` runs both tasks end to end.
"""

from ffjax.tasks import contacts, grasping, pushing, sensing

__all__ = ["contacts", "grasping", "pushing", "sensing"]
