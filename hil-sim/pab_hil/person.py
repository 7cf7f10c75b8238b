"""The person: the only scripted part of the world. The robot's side is all closed loop.

A script reacts to what it sees of the robot (where the hand is, who holds the object), the way
the user in the paper's experiment did, so its timing follows the robot's, however fast or slow
the machine running the nodes is.
"""

from __future__ import annotations

from . import world as w


class TakeAndReturn:
    """Shows the object, walks in once the robot holds it, takes it when the hand opens near the
    face (the world's handover), then walks away.

    With `takes_back`, the person instead takes the object from the hand while the arm is still
    approaching (the paper's variant) and steps away at once.
    """

    def __init__(
        self,
        show_at: float = 3.0,
        enter_after_grasp: float = 2.0,
        leave_after_handover: float = 1.5,
        takes_back: bool = False,
        take_back_after_approach: float = 0.5,
    ) -> None:
        self.show_at = show_at
        self.enter_after_grasp = enter_after_grasp
        self.leave_after_handover = leave_after_handover
        self.takes_back = takes_back
        self.take_back_after_approach = take_back_after_approach
        self.shown = False
        self.grasped_at: float | None = None
        self.entered = False
        self.approach_seen_at: float | None = None
        self.handed_over_at: float | None = None
        self.took_back_at: float | None = None
        self.left = False

    def step(self, world: w.World, s: w.Snapshot) -> None:
        if not self.shown and s.t >= self.show_at:
            self.shown = True
            world.show_object()
        if s.holder == w.HAND and self.grasped_at is None:
            self.grasped_at = s.t
        if self.grasped_at is not None and not self.entered:
            if s.t >= self.grasped_at + self.enter_after_grasp:
                self.entered = True
                world.person_enters()
        if self.takes_back and self.took_back_at is None and s.holder == w.HAND:
            # The arm approaches: its last delivered target is the face.
            approach = world.last_delivery("arm", within=0.5)
            if approach is not None and w.decode_position(approach.payload) == w.FACE_AT:
                if self.approach_seen_at is None:
                    self.approach_seen_at = s.t
                elif s.t >= self.approach_seen_at + self.take_back_after_approach:
                    self.took_back_at = s.t
                    world.person_takes_object()
                    world.person_leaves()
                    self.left = True
        if s.holder == w.PERSON_KEEPS and self.grasped_at is not None and self.handed_over_at is None:
            if self.took_back_at is None:
                self.handed_over_at = s.t
        if self.handed_over_at is not None and not self.left:
            if s.t >= self.handed_over_at + self.leave_after_handover:
                self.left = True
                world.person_leaves()
