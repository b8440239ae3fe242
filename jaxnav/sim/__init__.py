"""World and hardware simulators."""

from jaxnav.sim import landmark_world as landmark_world
