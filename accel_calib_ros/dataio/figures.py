"""
Figures written as files: a PNG is laid out, written atomically and closed.

matplotlib is imported only when a figure is written (commands start fast).
"""

from .atomic import atomic_path


def save_figure(fig, path):
    """Lay out ``fig``, write it as PNG to ``path`` atomically and close it."""
    import matplotlib.pyplot as plt
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90, format='png')
    plt.close(fig)
