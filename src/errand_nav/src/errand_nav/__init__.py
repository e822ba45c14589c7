"""errand_nav: crowd-aware goals for a learned controller (move_base's action, goals by phrase)."""
