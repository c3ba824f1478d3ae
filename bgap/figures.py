from bgap.runner.numerics import command

main = command("bgap.analysis.figures")
if __name__ == "__main__":
    main()
