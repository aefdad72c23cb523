"""The wording normaliser's lexicon: word lists, synonym table, rewrite patterns (data only; wording.py uses it).

Written as a general lexicon of everyday motion wording, then frozen: the held-out paraphrases (mogo_eval/
paraphrases.py) were written after it and never used to change it (docs/tca.md, "Measured"). Word lists are
space-separated strings; order matters only where a list says so (patterns are applied one after the other).
"""
from __future__ import annotations

import re


def words(text: str) -> set[str]:
    return set(text.split())


def by_target(groups: dict[str, str]) -> dict[str, str]:
    """{"walk": "stroll amble"} -> {"stroll": "walk", "amble": "walk"}."""
    return {w: target for target, ws in groups.items() for w in ws.split()}


# In this order: the arrows with a variation selector (U+FE0F) before the bare ones.
EMOJI = {"👋": " wave ", "🏃": " run ", "🚶": " walk ", "👏": " clap ", "🙇": " bow ", "👊": " punch ", "🥊": " punch ",
         "🦵": " kick ", "🪑": " sit down ", "🙌": " raise both arms ", "🕺": " dance ", "💃": " dance ",
         "🤸": " jump ", "⬅️": " left ", "➡️": " right ", "⬅": " left ", "➡": " right "}
# Applied in order, before apostrophes are dropped.
CONTRACTIONS = [(r"\bgonna\b", "going to"), (r"\bwanna\b", "want to"), (r"\bgotta\b", "got to"),
                (r"\b(\w+)in'", r"\1ing"), (r"\b(\w+)'(s|re|ll|ve|d|m)\b", r"\1"), (r"n't\b", " not")]
NUMBERS = {str(i): w for i, w in enumerate("one two three four five six seven eight nine ten eleven twelve".split(), 1)}
TIMES = {"1": "once", "one": "once", "2": "twice", "two": "twice", "3": "three times", "three": "three times",
         "4": "four times", "four": "four times", "5": "five times", "five": "five times"}
COUNTS = words("once twice times one two three four five six seven eight nine ten")


# Who does it: removed at a clause's start, and after causatives ("make the dude ...").
SUBJECTS = (r"(?:the|a|an|this|that|my|our|your|ur|some|one)?\s*(?:little\s+|lil\s+|old\s+|big\s+|young\s+)?"
            r"(?:person|persons|people|man|men|woman|women|guy|guys|dude|dudes|girl|boy|kid|child|lady|gentleman|"
            r"character|avatar|player|figure|model|actor|human|individual|fella|fellow|bro|homie|buddy|npc|"
            r"mannequin|robot|skeleton|body|subject|hero)"
            r"|someone|somebody|anyone|he|she|they|him|her|them|it|we|you|ya|u|i|me|us")
CAUSATIVE = re.compile(rf"\b(?:make|makes|made|making|have|has|had|let|lets|get|gets|got|want|wants|need|needs|"
                       rf"see|show|watch)\s+(?:{SUBJECTS})\s+(?:to\s+)?")
LEADING_SUBJECT = re.compile(rf"^(?:{SUBJECTS})\s+")
SUBJECT_IN_CAPTION = re.compile(r"^(?:(?:a|an|the|this|that)\s+\w+|someone|somebody|he|she|they)\s+")


# Auxiliaries / aspect verbs before the action verb: dropped when a motion verb follows.
HELPERS = words("is are was were be been being am will would should shall can could may might must going goes go "
                "went to start starts started starting begin begins began beginning keep keeps kept keeping try "
                "tries tried want wants wanted need needs needed got get gets has have had just then now also "
                "suddenly proceeds proceed decides decide decided continue continues continued please do does did "
                "and gonna wanna gotta finally first next afterwards lastly again")
# Multi-word fillers (regexes between word boundaries, ";"-separated), removed in this order before single words.
FILLER_PHRASES = [rf"\b{p}\b" for p in (
    "can you;could you;would you;will you;i want;i would like;i need;lets see;kind of;kinda;sort of;sorta;a bit;"
    "a little bit;for me;for a bit;for a while;for a sec(?:ond)?;right now;or something;or whatever;you know;i guess;"
    "i think;if you can;thank you;thanks;here;there;on (?:the )?(?:screen|camera);"
    "in the (?:game|scene|animation|video);like a (?:boss|pro|champ|maniac|madman|crazy person);all of a sudden;"
    "nothing (?:fancy|special|crazy|complicated|else)").split(";")]
# Words that carry no motion: dropped anywhere.
FILLERS = words("yo hey ok okay so um uh umm erm hmm like just pls plz please lol lmao rofl bro bruh fam ngl tbh fr "
                "rn omg lil little some really real super totally literally basically actually very pretty quite "
                "kinda sorta now cool nice awesome epic dope sick gently casually happily sadly angrily excitedly "
                "proudly nervously lazily aight alright well hella mad lowkey highkey simply nicely tho though "
                "anyway anyways oh wow yeah yep sure")
# Possessives and function words: removed with an unknown word that follows them ("kicks [the ball]").
FUNCTION = words("the a an his her their my your ur its at to toward towards into onto on over across through with "
                 "of some in from for by around off like this that these those him them it while near next "
                 "against along up down out")
# Words that cannot end a clause ("kicks with his" after "[the ball]" was dropped).
DANGLING = words("the a an his her their my your ur its at to toward towards into onto on with of some from for by "
                 "and this that while near against like through across over")


# Multi-word rewrites into caption phrasing, applied in order before verbs are found (base forms; inflected later).
_GO, _MOVE, _HEAD = "go|goes|went|going", "move|moves|moved|moving", "head|heads|headed|heading"
_DO, _DO_MAKE, _GIVE = "do|does|did|doing", "do|does|did|doing|make|makes|made", "give|gives|gave|giving"
PHRASES = [
    (r"\bback(?:s|ed|ing)? (?:it )?up\b", "walk backward"), (r"\bbackpedal(?:s|ed|ing|led|ling)?\b", "walk backward"),
    (rf"\b(?:{_GO}|{_MOVE}) (?:in reverse|backwards?)\b", "walk backward"),
    (r"\breverse(?:s|d)?\b(?! order)", "walk backward"), (rf"\b(?:{_GO}|{_MOVE}|{_HEAD}) back\b", "walk backward"),
    (r"\b(?:take|takes|took|taking|have|has|had|grab|grabs|grabbed) a (?:seat|chair|load off)\b", "sit down"),
    (r"\b(?:sit|sits|sat|sitting) (?:his|her|their|your|ur|my) (?:butt|ass|bum|self) down\b", "sit down"),
    (r"\bplop(?:s|ped|ping)?(?: down)?\b", "sit down"), (r"\bbe seated\b", "sit down"),
    (r"\b(?:say|says|said|saying) (?:hi|hello|hey|bye|goodbye|good bye|hiya|howdy)\b", "wave hello"),
    (rf"\b(?:{_GIVE}) (?:a |an )?(?:friendly )?(?:wave|hello)\b", "wave"),
    (r"\b(?:throw|throws|threw|throwing) (?:hands|fists|some hands|a few punches|punches|jabs)\b", "punch"),
    (r"\b(?:round of )?applause\b", "clap"), (rf"\b(?:{_GIVE}) (?:a )?clap\b", "clap"),
    (rf"\b(?:{_DO_MAKE}|pull|pulls|pulled|pulling) (?:a |an )?180\b", "turn around"),
    (rf"\b(?:{_DO_MAKE}|pull|pulls|pulled|pulling) (?:a |an )?360\b", "spin around"),
    (rf"\b(?:{_DO_MAKE}) (?:a |an )?90\b", "make a quarter turn"),
    (r"\babout[- ]face\b", "turn around"), (r"\bu[- ]?turn\b", "turn around"),
    (rf"\b(?:{_GO}|{_MOVE}|run|runs|ran|running) (?:around |round )?in (?:a |one )?"
     r"(?:big |small |large |little |full |wide |tight )?(?:circle|loop|ring)s?\b", "walk in a circle"),
    (rf"\b(?:{_DO}|walk|walks|walked|walking) (?:a )?(?:lap|loop)s?\b", "walk in a circle"),
    # exercise names that contain a verb: "do" carries them as the captions do ("does jumping jacks")
    (rf"\b(?:(?:{_DO}) )?(?:(?:some|a few|a set of) )?((?:\d+|one|two|three|four|five|six|seven|eight|nine|ten) )?"
     r"(jumping jacks?|star jumps?)\b", r"do \1\2"),
    (rf"\b(?:{_DO}|stand|stands|stood|standing) nothing\b", "stand still"),
    (r"\b(?:stay|stays|stayed|staying|stand|stands|stood|standing|wait|waits|waited|waiting|hang|hangs|hung|"
     r"hanging) (?:still|around|there|put|idle|in place)\b", "stand still"),
    (r"\b(?:chill|chills|chilled|chilling|chillin|vibe|vibes|vibed|vibing|idle|idles|idling|loiter|loiters|"
     r"loitering|relax|relaxes|relaxing|wait|waits|waiting|rest|rests|resting|pause|pauses|pausing|freeze|"
     r"freezes|froze|freezing)\b", "stand still"),
    (r"\b(?:put|puts|putting|throw|throws|threw|throwing|stick|sticks|stuck|sticking) (?:his |her |their |your |"
     r"ur |my |both )?(?:hands|arms) (?:up|in the air|up in the air|to the sky)\b", "raise both arms"),
    (r"^(?:both |his |her |their |your |ur |my |the )?(?:hands|arms) (?:up|in the air|up in the air|up high|"
     r"to the sky|overhead)\b", "raise both arms"),
    (rf"\b(?:step|steps|stepped|stepping|{_MOVE}|slide|slides|slid|sliding|scoot|scoots|scooted|scooting) "
     r"(?:to the |towards the |toward the |over to the |)(left|right)(?:wards?| side)?\b", r"sidestep to the \1"),
    (r"\bside ?step(?:s|ped|ping)?\b", "sidestep"), (r"\bstrafe(?:s|d)?\b|\bstrafing\b", "sidestep"),
    (r"\bcrab[- ]walk(?:s|ed|ing)?\b", "sidestep"),
    (rf"\b(?:{_GO}|{_MOVE}|{_HEAD}) (?:straight )?(forwards?|ahead)\b", r"walk \1"),
    (r"\b(?:bend|bends|bent|bending) (?:over|at the waist)\b", "bow"),
    (r"\b(?:hit|hits|hitting|drop|drops|dropped|dropping|get|gets|got|getting) (?:down )?(?:low|into a squat)\b",
     "squat down"),
    (r"\bon the spot\b", "in place"), (r"\bin one place\b", "in place"),
    (r"\bwhere (?:he|she|they|it) (?:is|are|stands?)\b", "in place"),
    (r"\bcounter[- ]?clockwise\b", "counterclockwise"), (r"\banti[- ]?clockwise\b", "counterclockwise"),
    (r"\b(?:a )?couple (?:of )?times\b", "twice"), (r"\b(?:a )?few times\b", "three times"),
    (r"\bx ?(\d+)\b", r"\1 times"), (r"\b(\d+) ?x\b", r"\1 times"),
    (r"\bwith (?:his|her|their|your|ur|my|the) (left|right)\b(?! (?:hand|arm|leg|foot|fist|side|shoulder))",
     r"with \1 hand"),
]

# Verbs a prompt may use (base forms) and what they mean in the captions' vocabulary, applied only where the
# caption index does not know the word itself.
SYNONYMS = by_target({
    "walk": "stroll amble saunter stride strut wander trudge mosey hike march tread pace waddle stomp tiptoe "
            "promenade trek advance",
    "walk backward": "retreat recede",
    "run": "jog sprint dash race rush bolt scurry hustle zoom gallop scamper charge speed",
    "jump": "hop leap bounce spring bound vault skip pounce lunge", "wave": "greet salute hail beckon",
    "kick": "boot punt", "squat": "crouch kneel duck hunker dip stoop", "turn": "rotate pivot spin twirl swivel whirl",
    "sit": "perch settle", "punch": "hit strike jab box sock smack slug pummel spar fight uppercut",
    "clap": "applaud cheer", "sidestep": "shuffle slide scoot strafe", "raise": "lift hoist elevate reach hold",
    "stand": "idle wait stay linger loiter chill", "bow": "curtsy curtsey nod",
})
# More base forms recognised as verbs (besides the synonym table's words and the captions' own verbs).
BASE_VERBS = words("walk run jump wave kick squat turn sit punch clap sidestep raise stand bow step take make do throw "
                   "swing bend lower lift move hop leap jog sprint spin box jab applaud shuffle put bring dance go "
                   "stomp rise stretch shake look nod lean crawl climb fall dive roll catch pick swim wiggle flap "
                   "circle")
# Irregular and -es forms -> base form ("form:base" pairs).
IRREGULAR = dict(pair.split(":") for pair in (
    "ran:run running:run sat:sit sitting:sit stood:stand threw:throw took:take spun:spin swung:swing bent:bend went:go "
    "gone:go did:do done:do made:make held:hold brought:bring leapt:leap sprang:spring knelt:kneel fell:fall rose:rise "
    "risen:rise got:get lay:lie lying:lie hit:hit strode:stride slid:slide shook:shake dove:dive has:have is:be are:be "
    "was:be were:be does:do goes:go boxes:box punches:punch crouches:crouch stretches:stretch reaches:reach "
    "marches:march dashes:dash rushes:rush lunges:lunge").split())
# Light verbs: in "do a hop", "give a little wave", "do 3 squats" the noun after them is the action.
LIGHT_VERBS = words("do does did doing give gives gave giving perform performs performed performing bust busts pull "
                    "pulls throw throws threw throwing take takes took taking make makes made making have has hit "
                    "hits nail nails land lands execute executes")
# Those nouns, and the verb each stands for.
NOUN_VERBS = {**{w: w for w in "hop jump leap kick squat wave bow punch jab clap spin sprint jog run walk sidestep "
                               "turn lunge".split()},
              **{w + "s": w for w in "hop jump leap kick squat wave bow clap spin jab lunge".split()},
              **by_target({"walk": "stroll", "spin": "twirl", "bow": "curtsy", "punch": "uppercut hook punches"})}
# Nouns of two words whose words are never the verb ("does jumping jacks" jumps no more than it jacks).
COMPOUND_NOUNS = {("jumping", "jacks"), ("jumping", "jack"), ("star", "jumps"), ("star", "jump")}
# Verbs that stand for the action only when no motion verb follows ("takes a seat", "does ...").
WEAK_VERBS = words("do go get have start keep make take")


KEEP_ADVERBS = words("slowly quickly calmly fast slow quick rapidly briskly swiftly")   # kept before the verb
# Word forms replaced by the captions' own (adverbs, directions, possessives) where the captions lack them.
WORD_MAP = by_target({"quickly": "quick fast rapidly swiftly briskly speedily hastily", "slowly": "slow leisurely",
                      "backward": "backwards", "forward": "forwards ahead", "left": "leftward leftwards",
                      "right": "rightward rightwards", "up": "upward upwards", "down": "downward downwards",
                      "their": "your ur my its"})
# Direction words whose disagreement with the prompt makes a caption wrong, whatever the embedding says.
OPPOSITES = {"left": "right", "right": "left", "forward": "backward", "backward": "forward",
             "clockwise": "counterclockwise", "counterclockwise": "clockwise"}
DIRECTIONS = set(OPPOSITES) | words("sideways circle place both backwards around")


# Clause boundaries, strongest first. "X before Y" keeps the order, "X after Y" swaps it (AFTER).
SEQ_SPLIT = re.compile(r"\s*(?:" + "|".join(rf",?\s*\b{w}\b" for w in (
    "and then;and after that;and afterwards;after that;afterwards;afterward;then;followed by;and finally;finally;next;"
    "and next;once done;once finished;before").split(";"))
                       + r"|[.;!?]+|,|\s+-+\s+|\s*&\s*|\s*->\s*|\s*=>\s*|\s*\+\s*)\s*")
AFTER = re.compile(r"^(.*\S)\s+after\s+(?!that\b)(.+)$")
# Words skipped to find a caption's verb after its subject or after "then" (wording.caption_verbs).
CAPTION_VERB_SKIP = KEEP_ADVERBS | words("first then also and that afterwards")
