"""Ground floor: precision policy, parameter groups and layouts, metrics, XLA helpers, JSON, shape buckets, joint trigonometry. Imports no other jaxcal room."""
