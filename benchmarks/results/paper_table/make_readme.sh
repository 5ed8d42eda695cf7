#!/usr/bin/env bash
# Regenerates benchmarks/results/paper_table/README.md from the recorded JSON files.
# Run from benchmarks/: bash results/paper_table/make_readme.sh
set -e
P=results/paper_table O=results/orientation
{
python3 paper_table.py $P/paper_table_presets.json $P/paper_table_position_seeds5-9.json \
    $P/paper_table_presets_MARAOrient_eval_cpu.json $P/paper_table_presets_MARACollisionOrient_eval_cpu.json
echo
echo "The Orient rows' times come from the GPU run's probe, which ran the deployed IK rule of"
echo "commit 159f656 (a standoff down to 0.02 rad, no hold, no IK-alone zone); their accuracy"
echo "columns are the committed rule's (the saved policies, \`params/\`, evaluated again on the CPU)."
echo
echo "## Ten seeds of the Orient tasks (study 27), two sets of evaluation episodes"
echo
echo "The \`orient_first\` preset (written out as overrides of \`default\`: the run predates"
echo "\`--preset task\`), seeds 0-9 per task, three programs sharing one H100 (times are not a"
echo "single user's; 20-step probe), the policies (\`results/orientation/params/study27_loose_*\`)"
echo "evaluated again on the CPU with the committed IK rule: with the paper's episodes"
echo "(\`EvalConfig.seed\` 0), then with other ones (\`--eval-seed 3\`)."
echo
python3 paper_table.py $O/study27_loose_mco.json $O/study27_loose_mao.json \
    $O/study27_loose_mco_eval_cpu.json $O/study27_loose_mao_eval_cpu.json | sed -n '/^| task/,/^$/p' | sed '/^$/d'
python3 paper_table.py $O/study27_loose_mco.json $O/study27_loose_mao.json \
    $O/study27_loose_mco_eval_seed3_cpu.json $O/study27_loose_mao_eval_seed3_cpu.json \
    | sed -n '/^|---/,/^$/p' | tail -n +2 | sed '/^$/d' \
    | sed 's/^| MARA\([A-Za-z]*\) |/| MARA\1, other episodes (eval seed 3) |/'
echo
echo "Commands: \`python benchmarks/orientation_params_eval.py results/orientation/params/study27_loose_mco"
echo "--task MARACollisionOrient --seeds 0 1 2 3 4 5 6 7 8 9 [--eval-seed 3]\` (and mao / MARAOrient);"
echo "this README: \`bash results/paper_table/make_readme.sh\` (from benchmarks/)."
} > $P/README.md
