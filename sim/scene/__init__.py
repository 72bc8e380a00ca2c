"""The scene: a TOML file validated into a frozen :class:`sim.scene.load.Scene`, one module per
group of tables (sheet, boundary, shapes, run) on the bounded types of ``fields``."""
