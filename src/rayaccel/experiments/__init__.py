"""The lecture's experiments, one module each; every one writes a markdown table and a plot."""
