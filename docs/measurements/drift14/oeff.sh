#!/bin/bash
# $1 = before|after ; runs the outsider drift effects through tvsctl analyze
cd /work/wt/drift14
PP=""; [ "$1" == before ] && PP=/tmp/d14/before
mkdir -p /tmp/d14/oset_$1
printf "o15064\no15065\no15066\no15067\no15068\no15069\no15070\no15071\n" > /tmp/d14/n15
printf "o16064\no16065\no16066\no16067\no16068\no16069\no16070\no16071\n" > /tmp/d14/n16
printf "o12112\no12113\no12115\n" > /tmp/d14/n12
printf "o13113\no13114\n" > /tmp/d14/n13
printf "o14112\no14114\n" > /tmp/d14/n14
for sd in 15 16; do PYTHONPATH=$PP nice -n 19 .venv/bin/python scripts/outsider_run.py run /tmp/d14/oset_$1 /tmp/d14/oeff.$1.jsonl --seed $sd --reps 4 --nulls 0 --sizes 6,20 --names /tmp/d14/n$sd; done
PYTHONPATH=$PP nice -n 19 .venv/bin/python scripts/outsider_run.py run /tmp/d14/oset_$1 /tmp/d14/oeff.$1.jsonl --seed 12 --reps 2 --nulls 80 --sizes 6,20 --names /tmp/d14/n12
PYTHONPATH=$PP nice -n 19 .venv/bin/python scripts/outsider_run.py run /tmp/d14/oset_$1 /tmp/d14/oeff.$1.jsonl --seed 13 --reps 2 --nulls 80 --sizes 6,20 --names /tmp/d14/n13
PYTHONPATH=$PP nice -n 19 .venv/bin/python scripts/outsider_run.py run /work/wt/outsider14/set /tmp/d14/oeff.$1.jsonl --seed 14 --reps 2 --nulls 80 --sizes 6,20 --names /tmp/d14/n14
