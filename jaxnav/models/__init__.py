"""Pure sensor and motion models."""

from jaxnav.models import hf_rfid as hf_rfid, landmarks as landmarks, motion as motion
