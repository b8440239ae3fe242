"""Pure sensor and motion models."""

from jaxnav.models import landmarks as landmarks, motion as motion
