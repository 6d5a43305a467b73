"""Using the twin: replaying a push (``r2s predict``) and planning a removal order
(``r2s declutter``) in PyBullet on ``export/``."""
