program 66
# DROOG_DUN: dry run of the thin plate's two seams.
move approach 10
weld seam_1 45
move between 10
weld seam_2 45
move home 10
