"""Foot-mounted inertial navigation: strapdown mechanisation, the GLRT stance detector, the ZUPT-aided
error-state filter and the federated filter that adds UWB positions and magnetic heading (issue 26).

* ``models.foot.mechanisation`` — quaternion strapdown, leveling;
* ``models.foot.stance`` — the SHOE / GLRT zero-velocity detector (Skog et al. 2010), stride counting;
* ``models.foot.federated`` — the master fusion and information sharing (Carlson 1990);
* ``models.foot.ins`` — :func:`~models.foot.ins.run_foot_ins`: the INS and its local filters;
* ``models.foot.body`` — the body's track from the foot's (the mid-stance rule).
"""

__all__ = ["mechanisation", "stance", "federated", "ins", "body"]
