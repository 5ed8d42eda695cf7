"""Pictures: C MuJoCo rendering of the arm, videos, and the figures of runs."""
