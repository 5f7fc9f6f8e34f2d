"""The scenario configuration: the schema (one section per component, variants as tagged
unions), the presets it starts from, the loader and the migration of the old flat schema."""

from .load import (  # noqa: F401
                   apply_setting,
                   load_scenario,
                   preset_names,
                   preset_scenario,
                   resolve_sensor,
                   scenario_from_text,
                   settings_of,
                   validate,
)
from .schema import *  # noqa: F401,F403
from .schema import OBJECT_KINDS, OBJECT_UP_AXES, REGISTERED_SIGMA, SENSOR_PRESETS, variant_name  # noqa: F401
