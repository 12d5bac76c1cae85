program 65
# DROOG_DIK: dry run of the thick plate's two seams.
move approach 10
weld seam_1 45
move between 10
weld seam_2 45
move home 10
