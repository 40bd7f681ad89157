#!/usr/bin/python3
"""One figure per scene for docs/studies/mlt.md: the render of each delayed-rejection variant next to its stage map.

    tools/mlt_stage_figure.py OUT.png DIR SCENE VARIANT...

DIR holds SCENE-VARIANT.exr and SCENE-VARIANT_stages.png as `kelvin ... -o DIR/SCENE-VARIANT.exr` writes them
(docs/studies/mlt.md gives the commands). The EXR is shown in sRGB through oiiotool (Debian: openimageio-tools).
"""
import os
import subprocess
import sys
import tempfile

import matplotlib

matplotlib.use("Agg")
import matplotlib.image as mpimg  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402


def main(argv):
    if len(argv) < 4:
        sys.stderr.write(__doc__)
        return 2
    out, d, scene, variants = argv[0], argv[1], argv[2], argv[3:]
    fig, axes = plt.subplots(2, len(variants), figsize=(3.2 * len(variants), 6.6), squeeze=False)
    with tempfile.TemporaryDirectory() as tmp:
        for i, v in enumerate(variants):
            stem = os.path.join(d, "%s-%s" % (scene, v))
            png = os.path.join(tmp, "%d.png" % i)
            subprocess.run(["oiiotool", stem + ".exr", "--ch", "R,G,B", "--colorconvert", "linear", "sRGB",
                            "-d", "uint8", "-o", png], check=True)
            axes[0][i].imshow(mpimg.imread(png), interpolation="nearest")
            axes[0][i].set_title(v, fontsize=10)
            axes[1][i].imshow(mpimg.imread(stem + "_stages.png"), interpolation="nearest")
            axes[1][i].set_title("stage map G / (R + G + 0.01)", fontsize=9)
            for a in (axes[0][i], axes[1][i]):
                a.set_xticks([])
                a.set_yticks([])
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
