"""
Figures written as files: a PNG is laid out, written atomically and closed.

matplotlib is imported only when a figure is written (commands start fast).
"""

from .atomic import atomic_file


def save_figure(fig, path):
    """Lay out ``fig``, write it as PNG to ``path`` atomically and close it."""
    import matplotlib.pyplot as plt
    fig.tight_layout()
    try:
        with atomic_file(path) as f:
            fig.savefig(f, dpi=90, format='png')
    finally:
        plt.close(fig)
