"""3D legged robots on a free-flyer base: the model with its named point feet (:mod:`.model`),
the contact dynamics of any set of stance feet and their rigid impacts (:mod:`.contact`), the
rigid impact with unilateral contacts, a QP in the impulses (:mod:`.impact`), the
contact checks of the planar walker generalised to 3D (:mod:`.checks`), the standing controller
with its QP allocation under the stance contacts (:mod:`.control`), feet leaving and reaching
the ground (:mod:`.events`), the closed loop that steps the robot standing, pushed, on a
stance schedule (:mod:`.stand`), a trot on it: a phase per diagonal pair and whole-body
inverse dynamics (:mod:`.trot`), its Poincaré map (:mod:`.poincare`), feedback error learning
on it in an unknown world (:mod:`.learn`), and MuJoCo as its plant (:mod:`.mujoco_plant`,
:mod:`.mujoco_stand`).

Imports from feltool: ``walking.checks`` (the walker's :class:`NotWalking` and its kinds) and
what the rest of ``walking`` may import (``robot``, ``dynamics``, ``errors``).
"""
